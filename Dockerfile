# softsensor estimator daemon: `softsensor run` (poller, lab input, estimator, recorder on an
# embedded Zenoh peer). Configuration comes from outside (/config), data goes to /data.
#
#   docker build -t softsensor .
#   docker run -d --name softsensor -v /etc/softsensor:/config:ro -v softsensor-data:/data \
#       -p 127.0.0.1:7447:7447 softsensor --config /config/dryer1.toml --plc 10.0.0.20:502
#
# BASE: any image with Python >= 3.11 whose `pip` and `python` are on PATH (the public slim
# image by default; tests/test_dockerfile.py builds from a local Debian base where Docker Hub
# is out of reach).
ARG BASE=python:3.11-slim
FROM ${BASE}

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    NUMBA_CACHE_DIR=/var/cache/softsensor/numba

# an unprivileged user owning only the data, the config copy and the compiled-model cache
RUN useradd --system --uid 10001 --user-group --home-dir /data --shell /usr/sbin/nologin \
        softsensor \
    && mkdir -p /data /config "$NUMBA_CACHE_DIR" \
    && chown softsensor:softsensor /data /config "$NUMBA_CACHE_DIR"

WORKDIR /opt/softsensor
COPY pyproject.toml README.md LICENSE ./
COPY softsensor ./softsensor
RUN pip install . && rm -rf /opt/softsensor/build

# the reference plant and its tag map, used when no config is mounted over /config
COPY --chown=10001:10001 config/dryer1.toml config/tagmap_dryer1.toml /config/

USER softsensor
# compile the model once at build time, so the daemon starts in seconds
RUN python -c "from softsensor.model import DryerModel; from softsensor.plantconfig import \
load_plant_config; m = DryerModel(load_plant_config()); \
m.simulate(m.nominal_inputs()[None, None, :].repeat(2, axis=1))"

WORKDIR /data
VOLUME ["/config", "/data"]
# Zenoh on every interface of the container (publish the port on the host as needed);
# recordings in /data/recordings, checkpoint in /data/state, lab drop in /data/lab-drop (the
# [service] defaults are relative to the working directory). Arguments given to `docker run`
# replace CMD only.
EXPOSE 7447
ENTRYPOINT ["softsensor", "run", "--listen", "tcp/0.0.0.0:7447"]
CMD ["--config", "/config/dryer1.toml"]
