# planar-pose inference service (reference: docs/service.md).
# Stage "build": a venv with the base install (`pip install .` of service/ only: no torch, no
# training code; setuptools' package search finds no `train` in this context).
# Stage "runtime": slim Python, that venv, the model folder (every models/<name>.onnx with its
# card; chessboard-corners-160x120 answers /v1/predict), a non-root user, one worker process per CPU.
#   docker build -t planar-pose .  &&  docker run --read-only -v pose-data:/data -p 8000:8000 planar-pose
# (a read-only root needs no other flag: cameras in the /data volume, temporary files in /dev/shm)
# BASE_IMAGE lets a locally made stand-in of python:3.11-slim be used (docs/service.md).
ARG BASE_IMAGE=python:3.11-slim

FROM ${BASE_IMAGE} AS build
WORKDIR /src
COPY pyproject.toml README.md ./
# The dependencies (pyproject's list) in a layer of their own: a change to the code alone
# rebuilds from the next COPY on, in seconds.
RUN python -c "import tomllib; print(*tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies'], sep='\n')" > requirements.txt \
    && python -m venv /opt/venv && /opt/venv/bin/pip install --no-cache-dir -r requirements.txt
COPY service ./service
RUN /opt/venv/bin/pip install --no-cache-dir --no-deps . \
    && /opt/venv/bin/pip uninstall --yes --quiet setuptools pip

FROM ${BASE_IMAGE} AS runtime
RUN groupadd --system --gid 10001 pose \
    && useradd --system --uid 10001 --gid pose --no-create-home --shell /usr/sbin/nologin pose \
    && install -d -o pose -g pose /data
COPY --from=build /opt/venv /opt/venv
COPY models/*.onnx models/*.json /app/models/
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    POSE_MODEL_DIR=/app/models \
    POSE_CAMERA_DB=/data/cameras.sqlite3
# the cameras the service learns (/v1/cameras): mount a volume here to keep them
VOLUME /data
WORKDIR /app
USER 10001:10001
EXPOSE 8000
HEALTHCHECK --interval=15s --timeout=3s --start-period=10s --retries=3 \
    CMD ["python", "-c", "import urllib.request as u; u.urlopen('http://127.0.0.1:8000/healthz', timeout=2)"]
CMD ["planar-pose-serve", "--host", "0.0.0.0", "--port", "8000"]
