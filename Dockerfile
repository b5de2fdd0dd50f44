# planar-pose inference service (see README "Service").
# Stage "build": a venv with the base install (`pip install .`: no torch, no training extras).
# Stage "runtime": slim Python, that venv, the default model, a non-root user.
#   docker build -t planar-pose .  &&  docker run -p 8000:8000 planar-pose
# tests/test_docker_recipe.py replays this file's install and command outside Docker.

FROM python:3.11-slim AS build
WORKDIR /src
COPY pyproject.toml README.md ./
COPY service ./service
COPY train ./train
RUN python -m venv /opt/venv && /opt/venv/bin/pip install --no-cache-dir .

FROM python:3.11-slim AS runtime
RUN groupadd --system --gid 10001 pose \
    && useradd --system --uid 10001 --gid pose --no-create-home --shell /usr/sbin/nologin pose
COPY --from=build /opt/venv /opt/venv
COPY models/default.onnx models/default.json /app/models/
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    POSE_MODEL_PATH=/app/models/default.onnx
WORKDIR /app
USER 10001:10001
EXPOSE 8000
HEALTHCHECK --interval=15s --timeout=3s --start-period=10s --retries=3 \
    CMD ["python", "-c", "import urllib.request as u; u.urlopen('http://127.0.0.1:8000/healthz', timeout=2)"]
CMD ["planar-pose", "serve", "--host", "0.0.0.0", "--port", "8000"]
