"""Estimator checkpoints on disk: written atomically, verified when read.

A checkpoint is one JSON document: ``{"format": "softsensor-checkpoint", "version": 2,
"saved_at_ns": ..., "unit": ..., "service": <EstimatorService.checkpoint()>, "sha256": ...}``
(the sha256 of the service state's canonical JSON; a checkpoint that fails it, or any check
of its fields, is refused with a one-line reason and the daemon moves it aside). It is written
to ``<path>.tmp`` in the same folder, flushed and fsync'ed, then renamed over ``<path>`` (an
atomic replace on POSIX), and the folder is fsync'ed; a daemon killed at any moment leaves
either the previous checkpoint or the new one, never a torn file. Floats go through ``repr``
in :mod:`json`, so a restored estimator continues bit for bit.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
import time
from pathlib import Path
from typing import Any

from softsensor.errors import ConfigError

FORMAT = "softsensor-checkpoint"
VERSION = 2  # 2: with the sha256 of the service state; 1 (no checksum) is still read
#: The largest checkpoint read [bytes]: one of the built-in plant is about 52 kB, so 300
#: times that; a path pointing at an endless file cannot grow the process (issue 49).
MAX_BYTES = 16 * 1024 * 1024


def state_digest(service_state: Any) -> str:
    """sha256 of the service state's canonical JSON: a torn or edited state is detected."""
    canon = json.dumps(service_state, allow_nan=True, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(canon.encode()).hexdigest()


class CheckpointStore:
    """Reads and atomically writes the checkpoint file at ``path``.

    Attributes
    ----------
    n_saved : int
        Checkpoints written by this store.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.tmp_path = self.path.with_name(self.path.name + ".tmp")
        self.n_saved = 0

    def load(self) -> dict[str, Any] | None:
        """The saved document, or None when there is no checkpoint yet.

        Raises :class:`ConfigError` naming the file when it exists but cannot be used.
        """
        try:
            data = self._read()
        except FileNotFoundError:
            return None
        except OSError as exc:
            raise ConfigError(f"{self.path}: cannot read checkpoint: {exc.strerror}") from exc
        try:
            doc = json.loads(data.decode("utf-8"))
        except ValueError as exc:
            raise ConfigError(f"{self.path}: checkpoint is not valid JSON (delete it or run "
                              f"with --no-resume)") from exc
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise ConfigError(f"{self.path}: not a softsensor checkpoint")
        if doc.get("version") not in (1, VERSION):
            raise ConfigError(f"{self.path}: checkpoint version {doc.get('version')!r}, "
                              f"expected {VERSION}")
        if not isinstance(doc.get("service"), dict):
            raise ConfigError(f"{self.path}: checkpoint has no service state")
        if doc["version"] == VERSION and doc.get("sha256") != state_digest(doc["service"]):
            raise ConfigError(f"{self.path}: checkpoint checksum does not match its content")
        t = doc.get("saved_at_ns")
        if not isinstance(t, int) or isinstance(t, bool) or not 0 < t < 2**63:
            raise ConfigError(f"{self.path}: checkpoint saved_at_ns is not a time")
        return doc

    def _read(self) -> bytes:
        """The file's bytes: a regular file (not a device or a FIFO, which is not waited
        on) of at most :data:`MAX_BYTES`, else a one-line :class:`ConfigError`."""
        fd = os.open(self.path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        with os.fdopen(fd, "rb") as f:
            if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
                raise ConfigError(f"{self.path}: not a regular file, so not a checkpoint "
                                  f"(delete it or run with --no-resume)")
            data = f.read(MAX_BYTES + 1)
        if len(data) > MAX_BYTES:
            raise ConfigError(f"{self.path}: more than {MAX_BYTES} bytes, far more than a "
                              f"checkpoint holds (delete it or run with --no-resume)")
        return data

    def move_aside(self) -> Path | None:
        """Rename an unusable checkpoint to ``<path>.bad-<ns>`` (kept for a post-mortem)."""
        if not self.path.exists():
            return None
        dest = self.path.with_name(f"{self.path.name}.bad-{time.time_ns()}")
        os.replace(self.path, dest)
        return dest

    def save(self, service_state: dict[str, Any], *, saved_at_ns: int, unit: str) -> None:
        """Write ``service_state`` atomically (module docstring)."""
        doc = {"format": FORMAT, "version": VERSION, "saved_at_ns": int(saved_at_ns),
               "unit": unit, "service": service_state, "sha256": state_digest(service_state)}
        data = json.dumps(doc, allow_nan=True, separators=(",", ":")).encode()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with open(self.tmp_path, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(self.tmp_path, self.path)
            _fsync_dir(self.path.parent)
        except OSError as exc:
            raise ConfigError(f"{self.path}: cannot write checkpoint: {exc.strerror}") from exc
        self.n_saved += 1

    def discard(self) -> None:
        """Remove the checkpoint (a fresh start)."""
        for p in (self.path, self.tmp_path):
            try:
                p.unlink()
            except FileNotFoundError:
                pass


def checkpoint_time_ns(doc: dict[str, Any]) -> int:
    """The latest time a checkpoint ``doc`` holds [ns]: when it was saved, or the service's
    clock, last tick or last closed window, whichever is latest (a checkpoint must not lie
    ahead of the messages it meets: the daemon's clock, a replayed day)."""
    state = doc.get("service", {})
    times = [doc["saved_at_ns"]] + [state.get(k) for k in ("now_ns", "ticked_end_ns",
                                                           "closed_end_ns")]
    return max(t for t in times if isinstance(t, int) and not isinstance(t, bool))


def check_fits(doc: dict[str, Any], unit: str, kind: str, where: str, hint: str = "") -> None:
    """Refuse a checkpoint ``doc`` (:meth:`CheckpointStore.load`) of another unit or
    estimator kind than the run's, in one line naming ``where`` (a configuration question,
    not damage: the file stays); ``hint`` is appended, e.g. ``" (use --no-resume)"``."""
    if doc.get("unit") != unit:
        raise ConfigError(f"{where}: checkpoint of unit {doc.get('unit')!r}, this run is "
                          f"{unit!r}{hint}")
    written = doc["service"].get("estimator_kind")
    if written != kind:
        raise ConfigError(f"{where}: written by estimator {written!r}, this run uses "
                          f"{kind!r}{hint}")


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:  # some file systems refuse fsync on a directory
        pass
    finally:
        os.close(fd)


__all__ = ["MAX_BYTES", "CheckpointStore", "check_fits", "checkpoint_time_ns"]
