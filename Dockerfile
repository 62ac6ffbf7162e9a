# softsensor estimator daemon: `softsensor run` (poller, lab input, estimator, recorder on an
# embedded Zenoh peer). Configuration comes from outside (/config), data goes to /data.
#
#   docker build -t softsensor .
#   docker run -d --name softsensor --read-only --tmpfs /tmp \
#       -v /etc/softsensor:/config:ro -v softsensor-data:/data \
#       -p 127.0.0.1:7447:7447 softsensor --config /config/dryer1.toml --plc 10.0.0.20:502
#
# BASE: any image with Python >= 3.11 whose `pip` and `python` are on PATH (the public slim
# image by default; tests/system/test_dockerfile.py builds from a local Debian base where Docker Hub
# is out of reach).
#
# Three stages so that an edit of the code rebuilds only its own small layer: `deps` installs
# the runtime dependencies of pyproject.toml (not the `offline` extra: no Optuna, Matplotlib,
# PyArrow) into a virtual environment; `app` installs the package on top; the final image is
# BASE plus the two copied layers, with no pip cache, no test suites and no bytecode of the
# dependencies (Python reads their sources; nothing is written at run time).
ARG BASE=python:3.11-slim

FROM ${BASE} AS deps
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
WORKDIR /src
COPY pyproject.toml ./
RUN python -m venv /opt/softsensor \
    && python -c "import tomllib; print('\n'.join(tomllib.load(open('pyproject.toml', \
'rb'))['project']['dependencies']))" > requirements.txt \
    && /opt/softsensor/bin/pip install --no-compile -r requirements.txt \
    && /opt/softsensor/bin/pip uninstall -y matplotlib pillow fonttools kiwisolver contourpy \
        cycler pyparsing setuptools pip \
    && find /opt/softsensor -depth \( -name __pycache__ -o -name tests \) \
        -type d -path "*/site-packages/*" -exec rm -rf {} +
# Matplotlib and its kin are removed in case a dependency declares them (filterpy did, until it
# moved to the offline extra; about 75 MB); setuptools and pip are not used at run time either. Extension modules
# shipped with their symbols (LLVM, zstd, Zenoh, many of NumPy's and SciPy's) are stripped
# where the base has apt: about 70 MB less, the code unchanged. (Not the wheels' bundled
# *.libs: auditwheel rewrote those, and strip breaks them.)
RUN if command -v apt-get >/dev/null && apt-get update -qq \
        && apt-get install -y -qq --no-install-recommends binutils >/dev/null; then \
      find /opt/softsensor -name "*.so" -type f -not -path "*.libs/*" \
          -exec strip --strip-unneeded {} +; \
    else echo "binutils not installable: libraries kept unstripped"; fi

FROM deps AS app
COPY README.md LICENSE ./
COPY softsensor ./softsensor
RUN python -m pip install --no-deps --target /opt/softsensor-app . \
    && rm -rf /src/build

FROM ${BASE}
ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PYTHONPATH=/opt/softsensor-app \
    PATH=/opt/softsensor/bin:$PATH \
    NUMBA_CACHE_DIR=/var/cache/softsensor/numba

# an unprivileged user owning only the data, the config copy and the compiled-model cache
RUN useradd --system --uid 10001 --user-group --home-dir /data --shell /usr/sbin/nologin \
        softsensor \
    && mkdir -p /data /config "$NUMBA_CACHE_DIR" \
    && chown softsensor:softsensor /data /config "$NUMBA_CACHE_DIR"

COPY --from=deps /opt/softsensor /opt/softsensor
COPY --from=app /opt/softsensor-app /opt/softsensor-app
RUN printf '#!/opt/softsensor/bin/python\nimport sys\nfrom softsensor.cli import main\n\
sys.exit(main())\n' > /opt/softsensor/bin/softsensor && chmod 755 /opt/softsensor/bin/softsensor

# the reference plant and its tag map, used when no config is mounted over /config (the
# package's copies: the repository's config/ only links to them)
COPY --chown=10001:10001 softsensor/data/dryer1.toml softsensor/data/tagmap_dryer1.toml /config/

USER softsensor
# compile the model once at build time, so the daemon starts in seconds (the cache is read
# at run time, also with a read-only root filesystem)
RUN python -c "from softsensor.model import DryerModel; from softsensor.plantconfig import \
load_plant_config; m = DryerModel(load_plant_config()); \
m.simulate(m.nominal_inputs()[None, None, :].repeat(2, axis=1))"

WORKDIR /data
VOLUME ["/config", "/data"]
# Zenoh on every interface of the container (publish the port on the host as needed; the
# README's "Locking the bus down" adds user/password authentication); recordings in
# /data/recordings, checkpoint in /data/state, lab drop in /data/lab-drop (the [service]
# defaults are relative to the working directory). Arguments given to `docker run` replace
# CMD only.
EXPOSE 7447
# healthy while the estimator thread ticks: `softsensor health` asks the daemon's health
# queryable over loopback and fails when it does not answer or reports the thread stalled
HEALTHCHECK --interval=60s --timeout=20s --start-period=120s --retries=3 \
    CMD ["softsensor", "health", "--config", "/config/dryer1.toml", \
         "--connect", "tcp/127.0.0.1:7447"]
STOPSIGNAL SIGTERM
ENTRYPOINT ["softsensor", "run", "--listen", "tcp/0.0.0.0:7447"]
CMD ["--config", "/config/dryer1.toml"]
