# One image for every service; compose picks the module to run.
FROM python:3.11-slim
WORKDIR /app
ENV PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1
COPY pyproject.toml README.md ./
COPY tiplog ./tiplog
COPY services ./services
COPY proto ./proto
RUN pip install .
# The vision image adds the network runtime: docker build --build-arg EXTRAS=vision
ARG EXTRAS=""
RUN if [ -n "$EXTRAS" ]; then pip install ".[${EXTRAS}]"; fi
USER 1000:1000
