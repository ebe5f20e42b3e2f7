# One image for every service; compose picks the module to run. Only the vision image adds
# torch: docker build --build-arg EXTRAS=vision (compose does so for the vision service).
FROM python:3.11-slim
WORKDIR /app
ENV PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1
# numba (fusion's kernels) caches compiled code beside the source by default; /app is not
# writable by the service user, so its cache goes where it may write.
ENV NUMBA_CACHE_DIR=/tmp/numba-cache
# The repository minus what .dockerignore leaves out (venv, tests, recordings, git).
COPY . .
ARG EXTRAS=""
RUN pip install ".${EXTRAS:+[$EXTRAS]}"
# The device and camera nodes are passed through by compose; dialout reads the serial port.
RUN useradd --uid 1000 --groups dialout,video --no-create-home tiplog
# Fusion's kernels compiled into that cache now (about half a minute), not on the cart while the
# first samples queue behind them (services/fusion/live/warmup.py).
RUN python -m services.fusion.live.warmup && chown -R tiplog /tmp/numba-cache
USER tiplog
