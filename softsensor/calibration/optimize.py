"""The Optuna study of the paper's section 3.3: TPE over the seven Table 1 multipliers.

* Search space: every parameter of the config's ``[parameters.<name>]`` tables within its
  ``[low, high]`` (Table 1), log-scaled where ``log = true`` (all seven span decades).
* Sampler: Optuna's TPE (:class:`optuna.samplers.TPESampler`), seeded. Its good set is the
  best 10 % of the trials (capped at 25), the paper's ``gamma = 0.1``, which is Optuna 5's
  default (passing ``gamma`` is deprecated). The first 10 trials are random; the very first
  trial of a new study is the config's own parameter values (the uncalibrated model).
* Objective: :mod:`softsensor.calibration.objective` (eq. 4 or the likelihood, after the inlet
  moisture's trajectory when it is estimated, plus the prior) over all segments, every trial
  from its own steady initial state.
* Pruning: the horizon runs in chunks (:class:`~softsensor.calibration.chunked_run.ChunkedRun`);
  after each chunk but the last the partial cost is reported and Optuna's
  :class:`~optuna.pruners.MedianPruner` stops trials worse than the median of earlier trials at
  the same point. A trial whose model solve fails is pruned with cost :data:`FAILED_COST` so
  that TPE learns to avoid that corner (user attribute ``solver_failed``).
* Batches: ``batch`` trials are asked at once and simulated through one batched model call
  per chunk (ask/tell interface).
* Cores: a batch's members run in the model's threads, one per core
  (:func:`~softsensor.model.dryer.for_members`; the kernels release the GIL). With the inlet
  moisture estimated every trial is two members (as it is and with the inlet moisture
  raised), so the default ``batch = 1`` already keeps two cores busy, and TPE sees every
  result before it proposes the next trial (``benchmarks/calibrate.py`` measures one core
  against two).
* Storage: in memory, a journal file, or any database URL Optuna accepts (sqlite,
  PostgreSQL, MySQL). Several processes or machines join one study through the same storage
  and study name; ``n_trials`` is the number of *finished* (complete or pruned) trials the
  study should hold, so a second run resumes an interrupted study and several workers share
  the budget (each stops when the study is full; concurrent workers may overshoot by at most
  one batch each).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import optuna
from optuna.distributions import FloatDistribution
from optuna.storages import BaseStorage, InMemoryStorage, JournalStorage
from optuna.storages.journal import JournalFileBackend, JournalFileOpenLock
from optuna.trial import FrozenTrial, Trial, TrialState

from softsensor.calibration.chunked_run import ChunkedRun
from softsensor.calibration.dataset import Segment
from softsensor.calibration.objective import ObjectiveSpec
from softsensor.calibration.settings import DEFAULT_STUDY_NAME
from softsensor.errors import ConfigError
from softsensor.model import DryerModel
from softsensor.plantconfig import PARAMETER_NAMES, PlantConfig, PlantSections

#: Objective reported for a trial whose model solve failed (far above any real objective).
FAILED_COST = 1.0e9
#: Trials TPE draws at random before it models the good and bad sets.
N_STARTUP_TRIALS = 10
#: File name endings read as an Optuna journal file when ``--storage`` is a plain path.
JOURNAL_SUFFIXES = (".log", ".journal", ".jsonl")


@dataclass(frozen=True)
class StudySettings:
    """How to run the study (see the module docstring)."""

    n_trials: int
    seed: int = 0
    storage: str | None = None
    study_name: str = DEFAULT_STUDY_NAME
    n_chunks: int = 4
    batch: int = 1
    prune: bool = True
    progress: bool = True

    def check(self) -> None:
        if self.n_trials < 1:
            raise ConfigError(f"--trials must be >= 1, got {self.n_trials}")
        if self.batch < 1:
            raise ConfigError(f"--batch must be >= 1, got {self.batch}")
        if self.n_chunks < 1:
            raise ConfigError(f"--chunks must be >= 1, got {self.n_chunks}")


def search_space(config: PlantConfig) -> dict[str, FloatDistribution]:
    """Table 1 bounds of every parameter as Optuna distributions (log where configured)."""
    return {n: FloatDistribution(config.parameters[n].low, config.parameters[n].high,
                                 log=config.parameters[n].log) for n in PARAMETER_NAMES}


def theta_of(params: dict[str, float]) -> np.ndarray:
    """Parameter dict -> vector in :data:`PARAMETER_NAMES` order."""
    return np.array([float(params[n]) for n in PARAMETER_NAMES])


def open_storage(url: str | None) -> BaseStorage:
    """An Optuna storage for ``--storage``.

    ``None``: in memory. ``journal:PATH`` or a path ending in .log/.journal/.jsonl: a journal
    file (safe for several processes on one file system). Anything with ``://`` (e.g.
    ``sqlite:///study.db``, ``postgresql://user@host/db``): Optuna's RDB storage.
    """
    if url is None:
        return InMemoryStorage()
    path = None
    if url.startswith("journal:"):
        path = url[len("journal:"):]
        path = path[2:] if path.startswith("//") else path
    elif "://" not in url:
        if not url.endswith(JOURNAL_SUFFIXES):
            raise ConfigError(f"--storage {url}: give a database URL (sqlite:///f.db, "
                              f"postgresql://...) or a journal file (journal:PATH or a path "
                              f"ending in {', '.join(JOURNAL_SUFFIXES)})")
        path = url
    if path is not None:
        p = Path(path)
        if not p.parent.is_dir():
            raise ConfigError(f"--storage {url}: directory {p.parent} does not exist")
        return JournalStorage(JournalFileBackend(str(p), lock_obj=JournalFileOpenLock(str(p))))
    try:
        return optuna.storages.RDBStorage(url)
    except Exception as exc:  # sqlalchemy raises many types for a bad URL or server
        raise ConfigError(f"--storage {url}: cannot open: {str(exc).splitlines()[0]}") from exc


def data_fingerprint(segments: Sequence[Segment], config: PlantConfig,
                     spec: ObjectiveSpec | None = None) -> str:
    """A short hash of the calibration problem: the data, the search space, the objective
    and the plant the trials simulate (every plant section but the unit's name, so also the
    structural keys a PARAMS.toml's ``[structure]`` sets, :mod:`softsensor.model.structure`).
    A study is only resumed or joined on the same problem: trials of another structure scored
    another model."""
    h = hashlib.sha256()
    for seg in segments:
        h.update(np.ascontiguousarray(seg.U).tobytes())
        h.update(np.nan_to_num(seg.Y).tobytes())
        h.update(seg.lab_time_ns.tobytes())
        h.update(seg.lab_value.tobytes())
    h.update(json.dumps(config.bounds().tolist()).encode())
    h.update(np.asarray(config.cost.weights()).tobytes())
    plant = {f.name: dataclasses.asdict(getattr(config, f.name))
             for f in dataclasses.fields(PlantSections) if f.name != "unit"}
    h.update(json.dumps(plant, sort_keys=True).encode())
    if spec is not None:
        h.update(repr((spec.cost, spec.prior_sigma, spec.prior_scale, spec.inlet,
                       None if spec.prior_center is None else spec.prior_center.tolist(),
                       spec.n_eff_ratio.tolist())).encode())
    return h.hexdigest()[:16]


def _sampler_seed(seed: int, created: bool) -> int:
    """The study's creator uses ``seed``; a worker joining an existing study mixes in its
    process id so that workers do not propose the same random trials."""
    if created:
        return int(seed)
    return int(np.random.SeedSequence([int(seed), os.getpid(), time.time_ns() % 2**32])
               .generate_state(1)[0])


def open_study(settings: StudySettings, config: PlantConfig, fingerprint: str
               ) -> tuple[optuna.Study, bool]:
    """Create the study, or load it when it exists in the storage; returns ``(study,
    created)``. A new study gets the config's parameter values as its first trial."""
    storage = open_storage(settings.storage)
    pruner = optuna.pruners.MedianPruner(n_startup_trials=N_STARTUP_TRIALS, n_warmup_steps=0)
    created = True
    try:
        study = optuna.create_study(
            storage=storage, study_name=settings.study_name, direction="minimize",
            sampler=optuna.samplers.TPESampler(seed=settings.seed,
                                               n_startup_trials=N_STARTUP_TRIALS),
            pruner=pruner)
    except optuna.exceptions.DuplicatedStudyError:
        created = False
        study = optuna.load_study(
            storage=storage, study_name=settings.study_name,
            sampler=optuna.samplers.TPESampler(seed=_sampler_seed(settings.seed, False),
                                               n_startup_trials=N_STARTUP_TRIALS),
            pruner=pruner)
    if created:
        study.set_user_attr("data_fingerprint", fingerprint)
        study.set_user_attr("seed", int(settings.seed))
        study.enqueue_trial({n: config.parameters[n].value for n in PARAMETER_NAMES},
                            user_attrs={"origin": "config"})
    else:
        other = study.user_attrs.get("data_fingerprint")
        if other is not None and other != fingerprint:
            raise ConfigError(f"--storage {settings.storage}: study {settings.study_name!r} was "
                              f"made on other data, bounds or plant structure; give another "
                              f"--study-name")
    return study, created


def count_trials(study: optuna.Study) -> dict[str, int]:
    """Trials of the study by state (``complete``, ``pruned``, ``fail``, ``running``...)."""
    counts: dict[str, int] = {}
    for t in study.get_trials(deepcopy=False):
        counts[t.state.name.lower()] = counts.get(t.state.name.lower(), 0) + 1
    return counts


def n_finished(study: optuna.Study) -> int:
    c = count_trials(study)
    return c.get("complete", 0) + c.get("pruned", 0)


@dataclass
class WorkerReport:
    """What one process did in the study."""

    trials: int = 0
    complete: int = 0
    pruned: int = 0
    failed: int = 0
    windows_simulated: int = 0
    windows_full: int = 0
    wall_time: float = 0.0
    numbers: list[int] = field(default_factory=list)


def _finish_batch(study: optuna.Study, model: DryerModel, segments: Sequence[Segment],
                  trials: list[Trial], spec: ObjectiveSpec, settings: StudySettings,
                  report: WorkerReport) -> None:
    theta = np.stack([theta_of(t.params) for t in trials])
    run = ChunkedRun(model, segments, theta, spec, settings.n_chunks)
    open_ = set(range(len(trials)))
    for t in trials:
        t.set_user_attr("worker", os.getpid())
    while not run.done and open_:
        live_before = np.flatnonzero(run.alive)
        report.windows_simulated += int(live_before.size * sum(
            int(b[min(run.step_index + 1, len(b) - 1)] - b[min(run.step_index, len(b) - 1)])
            for b in run.bounds))
        partial = run.advance()
        last = run.done
        for i, ev in partial.items():
            trial = trials[i]
            if not np.isfinite(ev.objective):
                trial.set_user_attr("solver_failed", True)
                trial.report(FAILED_COST, run.step_index - 1)
                study.tell(trial, state=TrialState.PRUNED)
                report.failed += 1
                open_.discard(i)
                continue
            if last:
                continue
            trial.report(ev.objective, run.step_index - 1)
            if settings.prune and trial.should_prune():
                study.tell(trial, state=TrialState.PRUNED)
                report.pruned += 1
                run.drop(i)
                open_.discard(i)
    if open_:
        full = run.partial(np.array(sorted(open_)))
        for i in sorted(open_):
            ev = full[i]
            trial = trials[i]
            for name, v in ev.fit.rmse.items():
                trial.set_user_attr(f"rmse_{name}", v)
            trial.set_user_attr("eq4", ev.fit.cost)
            trial.set_user_attr("prior", ev.prior)
            study.tell(trial, ev.objective)
            report.complete += 1
    report.trials += len(trials)
    report.windows_full += len(trials) * sum(s.n_windows for s in segments)
    report.numbers += [t.number for t in trials]


def run_trials(study: optuna.Study, model: DryerModel, segments: Sequence[Segment],
               config: PlantConfig, settings: StudySettings, spec: ObjectiveSpec,
               on_trial: Callable[[FrozenTrial | None], None] | None = None) -> WorkerReport:
    """Ask, evaluate and tell trials until the study holds ``settings.n_trials`` finished
    trials. A progress bar goes to stderr when ``settings.progress``. On an interrupt the
    trials in flight are marked failed, so that a resumed study does not wait for them."""
    from tqdm import tqdm

    space = search_space(config)
    report = WorkerReport()
    t0 = time.perf_counter()
    done = n_finished(study)
    bar = tqdm(total=settings.n_trials, initial=min(done, settings.n_trials), file=sys.stderr,
               desc="calibrate", unit="trial", disable=not settings.progress, leave=True,
               dynamic_ncols=True)
    trials: list[Trial] = []
    try:
        while True:
            c = count_trials(study)
            room = settings.n_trials - (c.get("complete", 0) + c.get("pruned", 0)
                                        + c.get("running", 0))
            if room <= 0:
                break
            trials = [study.ask(space) for _ in range(min(settings.batch, room))]
            _finish_batch(study, model, segments, trials, spec, settings, report)
            trials = []
            now = n_finished(study)
            bar.update(max(0, min(now, settings.n_trials) - bar.n))
            with contextlib.suppress(ValueError):
                bar.set_postfix(best=f"{study.best_value:.5g}", refresh=False)
            if on_trial is not None:
                on_trial(None)
    except BaseException:
        for t in trials:
            with contextlib.suppress(Exception):
                study.tell(t, state=TrialState.FAIL)
        raise
    finally:
        bar.close()
    report.wall_time = time.perf_counter() - t0
    return report


def first_trial_reaching(study: optuna.Study, value: float, rtol: float = 1e-12) -> int | None:
    """Number of the first complete trial whose cost is within ``rtol`` of ``value``."""
    for t in sorted(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)),
                    key=lambda t: t.number):
        if t.value is not None and t.value <= value * (1 + rtol):
            return t.number
    return None


def study_summary(study: optuna.Study) -> dict[str, Any]:
    """Counts, best trial and its cost, share of trials pruned."""
    c = count_trials(study)
    finished = c.get("complete", 0) + c.get("pruned", 0)
    out: dict[str, Any] = {"study_name": study.study_name, "counts": c,
                           "finished": finished,
                           "pruned_share": c.get("pruned", 0) / finished if finished else 0.0}
    try:
        best = study.best_trial
    except ValueError:
        return out
    out.update(best_trial=best.number, best_cost=best.value, best_params=dict(best.params))
    return out


__all__ = [
    "DEFAULT_STUDY_NAME",
    "FAILED_COST",
    "StudySettings",
    "WorkerReport",
    "count_trials",
    "data_fingerprint",
    "first_trial_reaching",
    "n_finished",
    "open_storage",
    "open_study",
    "run_trials",
    "search_space",
    "study_summary",
    "theta_of",
]
