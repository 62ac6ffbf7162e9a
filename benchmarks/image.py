"""The daemon's container image: built here, run, and its size against the 600 MB target.

    python benchmarks/image.py [--json OUT.json]

Builds the Dockerfile as it stands (only its ``BASE`` argument changed where Docker Hub is out
of reach: a Debian base made with ``debootstrap`` plus Debian's Python, the recipe in the
README's "In a container"), then runs the image with a read-only root filesystem until its
HEALTHCHECK reports ``healthy``, stops it with SIGTERM, and prints one
JSON object: the image size, the base's size, what the Dockerfile adds, the seconds to healthy
and to stop, the exit code, and whether the target (at most 600 MB, a clean stop) is met.
Exit status 0 when every check passes, 1 when one fails, 2 when no engine or base is there.

``tests/system/test_dockerfile.py`` (slow suite) uses the same functions.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The Debian base Python is put on when Docker Hub is out of reach (the README's "In a
#: container" says how to make it); ``SOFTSENSOR_DOCKER_BASE`` names another.
LOCAL_BASE = os.environ.get("SOFTSENSOR_DOCKER_BASE", "local/bookworm:base")
PUBLIC_BASE = "python:3.11-slim"
HOST_CA = Path("/etc/ssl/certs/ca-certificates.crt")
TAG = "softsensor-test/softsensor:latest"
#: The image size target [bytes] (issue 14).
MAX_IMAGE_BYTES = 600 * 10**6
#: Python on the Debian base, as the Dockerfile expects of BASE (``pip`` and ``python`` on
#: PATH). The host's CA bundle goes into this build-only layer so that pip reaches the package
#: index through the host's TLS proxy; the default image never sees it.
PYTHON_LAYER = """\
FROM {base}
RUN apt-get update && apt-get install -y --no-install-recommends python3 python3-venv \\
    && apt-get clean && rm -rf /var/lib/apt/lists/* && python3 -m venv /opt/python
COPY ca.crt /etc/ssl/certs/host-ca.crt
ENV PATH=/opt/python/bin:$PATH PIP_CERT=/etc/ssl/certs/host-ca.crt
"""


class Unavailable(Exception):
    """No engine, or no base image to build from: the reason."""


def docker(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(["docker", *args], capture_output=True, text=True, timeout=timeout)


def check_engine() -> None:
    """Raise :class:`Unavailable` unless a Docker engine answers."""
    if shutil.which("docker") is None:
        raise Unavailable("no docker client on PATH")
    info = docker("info", timeout=30)
    if info.returncode != 0:
        lines = (info.stderr or info.stdout).strip().splitlines()
        raise Unavailable(f"no Docker engine answers `docker info`: "
                          f"{lines[-1] if lines else '?'}")


def python_base(workdir: Path) -> str:
    """An image with Python to build FROM: the local Debian base with the Python layer, or
    the public default when the engine already holds it."""
    if docker("image", "inspect", LOCAL_BASE).returncode == 0:
        ctx = workdir / "python-layer"
        ctx.mkdir(exist_ok=True)
        (ctx / "Dockerfile").write_text(PYTHON_LAYER.format(base=LOCAL_BASE))
        shutil.copyfile(HOST_CA, ctx / "ca.crt")
        tag = "softsensor-test/python:bookworm"
        r = docker("build", "-t", tag, str(ctx), timeout=1200)
        if r.returncode != 0:
            raise RuntimeError(f"building the Python base failed: {r.stderr[-2000:]}")
        return tag
    if docker("image", "inspect", PUBLIC_BASE).returncode == 0:
        return PUBLIC_BASE
    raise Unavailable(f"neither {LOCAL_BASE} nor {PUBLIC_BASE} is in the engine (make the "
                      "first with `debootstrap --variant=minbase bookworm ROOTFS` and `tar -C "
                      f"ROOTFS -c . | docker import - {LOCAL_BASE}`)")


def build(base: str, tag: str = TAG) -> None:
    r = docker("build", "--build-arg", f"BASE={base}", "-t", tag, str(ROOT), timeout=2400)
    if r.returncode != 0:
        raise RuntimeError(f"docker build failed: {r.stderr[-3000:]}")


def size_bytes(image: str) -> int:
    return int(docker("image", "inspect", "-f", "{{.Size}}", image).stdout.strip())


def run_healthy_and_stop(tag: str = TAG, limit_s: float = 180.0) -> dict:
    """Run the image's daemon (read-only root, health checked every 2 s) until healthy, then
    ``docker stop`` it; what was seen."""
    name = f"softsensor-bench-{os.getpid()}"
    docker("rm", "-f", name)
    r = docker("run", "-d", "--name", name, "--read-only", "--tmpfs", "/tmp",
               "--health-interval", "2s", "--health-start-period", "120s", tag)
    if r.returncode != 0:
        raise RuntimeError(f"docker run failed: {r.stderr[-2000:]}")
    try:
        t0, status = time.monotonic(), "starting"
        while status != "healthy" and time.monotonic() - t0 < limit_s:
            time.sleep(1.0)
            status = docker("inspect", "-f", "{{.State.Health.Status}}", name).stdout.strip()
        healthy_s = time.monotonic() - t0
        uid = docker("exec", name, "id", "-u").stdout.strip()
        t1 = time.monotonic()
        docker("stop", "-t", "30", name, timeout=60)
        stop_s = time.monotonic() - t1
        code = int(docker("inspect", "-f", "{{.State.ExitCode}}", name).stdout.strip())
        logs = docker("logs", name)
        text = logs.stdout + logs.stderr
        return {"health": status, "healthy_after_s": round(healthy_s, 1), "uid": uid,
                "stop_s": round(stop_s, 2), "exit_code": code,
                "tracebacks": text.count("Traceback"), "stopped_line": "event=stopped" in text}
    finally:
        docker("rm", "-f", name)


def measure() -> dict:
    check_engine()
    with tempfile.TemporaryDirectory() as tmp:
        base = python_base(Path(tmp))
    t0 = time.monotonic()
    build(base)
    built_s = time.monotonic() - t0
    image, base_size = size_bytes(TAG), size_bytes(base)
    out = {"image": TAG, "base": base, "image_mb": round(image / 1e6, 1),
           "base_mb": round(base_size / 1e6, 1),
           "added_by_dockerfile_mb": round((image - base_size) / 1e6, 1),
           "target_mb": MAX_IMAGE_BYTES / 1e6, "build_s": round(built_s, 1),
           **run_healthy_and_stop()}
    out["met"] = bool(image <= MAX_IMAGE_BYTES and out["health"] == "healthy"
                      and out["exit_code"] == 0 and out["tracebacks"] == 0
                      and out["uid"] not in ("0", ""))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", default=None, metavar="OUT.json", help="also write the result")
    args = ap.parse_args()
    try:
        out = measure()
    except Unavailable as exc:
        print(f"image benchmark skipped: {exc}", file=sys.stderr)
        return 2
    text = json.dumps(out, indent=2)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n")
    return 0 if out["met"] else 1


if __name__ == "__main__":
    sys.exit(main())
