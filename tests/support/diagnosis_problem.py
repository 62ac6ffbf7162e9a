"""The diagnosis problem of a day as the diagnosis tests build it: the day's windows, a split
with at least one lab result on the fitted part, the config's parameters, a lab noise of 0.003
kg/kg."""

from __future__ import annotations

from softsensor.diagnosis.day_windows import day_windows
from softsensor.diagnosis.problem import Problem, choose_split


def make_problem(cfg, model, day) -> Problem:
    w = day_windows(day, cfg)
    return Problem(cfg, model, w, choose_split(w, min_labs=1), model.theta0, 0.003)


__all__ = ["make_problem"]
