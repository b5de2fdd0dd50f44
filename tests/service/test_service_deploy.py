"""deploy/: the Kubernetes manifests agree with the Dockerfile and the service settings."""

from __future__ import annotations

from typing import Any

import pytest
import yaml
from service_support import ROOT

from service.settings import Settings

DEPLOY = ROOT / "deploy"


def manifest(name: str) -> dict[str, Any]:
    return yaml.safe_load((DEPLOY / name).read_text())


DEPLOYMENT = manifest("deployment.yaml")
POD = DEPLOYMENT["spec"]["template"]["spec"]
CONTAINER = POD["containers"][0]


def test_probes_and_port() -> None:
    assert CONTAINER["readinessProbe"]["httpGet"]["path"] == "/readyz"
    assert CONTAINER["livenessProbe"]["httpGet"]["path"] == "/healthz"
    (port,) = CONTAINER["ports"]
    assert port["containerPort"] == 8000 and "EXPOSE 8000" in (ROOT / "Dockerfile").read_text()
    for probe in ("readinessProbe", "livenessProbe", "startupProbe"):
        assert CONTAINER[probe]["httpGet"]["port"] == port["name"]


def test_env_are_real_settings() -> None:
    """Every POSE_* variable names a Settings field and its value validates."""
    values = {}
    for var in CONTAINER["env"]:
        assert var["name"].startswith("POSE_")
        field = var["name"].removeprefix("POSE_").lower()
        assert field in Settings.model_fields, var["name"]
        if "value" in var:
            values[field] = var["value"]
    settings = Settings(**values)
    grace = POD["terminationGracePeriodSeconds"]
    # the service drains itself after SIGTERM (POSE_DRAIN_S), no preStop sleep before it
    assert "lifecycle" not in CONTAINER and settings.drain_s >= 5
    assert grace > settings.drain_s + settings.graceful_timeout_s


def test_resources_user_and_selectors() -> None:
    assert {"requests", "limits"} <= set(CONTAINER["resources"])
    assert "USER 10001" in (ROOT / "Dockerfile").read_text()
    assert POD["securityContext"]["runAsUser"] == 10001
    labels = DEPLOYMENT["spec"]["template"]["metadata"]["labels"]
    service = manifest("service.yaml")
    assert service["spec"]["selector"].items() <= labels.items()
    assert service["spec"]["ports"][0]["targetPort"] == CONTAINER["ports"][0]["name"]
    hpa = manifest("hpa.yaml")
    assert hpa["spec"]["scaleTargetRef"]["name"] == DEPLOYMENT["metadata"]["name"]
    assert hpa["spec"]["minReplicas"] <= hpa["spec"]["maxReplicas"]


@pytest.mark.parametrize("name", ["deployment.yaml", "service.yaml", "hpa.yaml"])
def test_kustomization_lists_every_manifest(name: str) -> None:
    assert name in manifest("kustomization.yaml")["resources"]


#: The memory limit's formula (deploy/deployment.yaml): a worker with its default model, one
#: graph loading beyond the budget, a 50 MP decode per inference job (MiB).
WORKER_MIB, LOADING_MIB, DECODE_MIB = 180, 40, 150


def test_memory_limit_covers_the_models_budget_and_the_jobs() -> None:
    values = {v["name"]: v["value"] for v in CONTAINER["env"] if "value" in v}
    limit = CONTAINER["resources"]["limits"]["memory"]
    assert limit.endswith("Mi"), limit
    budget = float(values["POSE_MODEL_MEMORY_MB"])
    jobs = int(values["POSE_INFERENCE_WORKERS"]) * int(values["POSE_WORKERS"])
    assert int(limit[:-2]) >= WORKER_MIB + budget + LOADING_MIB + jobs * DECODE_MIB
