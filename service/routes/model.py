"""The served models: the default model's card, the list of models, reloading the folder."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

import anyio
from fastapi import APIRouter

from service.deps import AUTHORISED, PredictorDep, SettingsDep, StateDep
from service.predictor import Predictor
from service.schemas import ERROR_RESPONSES, ModelInfo, ModelsResponse, ReloadResponse

router = APIRouter(tags=["models"], dependencies=AUTHORISED)


def model_info(name: str, predictor: Predictor, default: bool) -> ModelInfo:
    card = predictor.model.card
    profile = card.get("profile")
    return ModelInfo(
        name=name,
        default=default,
        card_name=predictor.model.name,  # the card's; a copied file keeps it
        version=card.get("version"),
        profile=profile.get("name") if isinstance(profile, dict) else profile,
        input=list(predictor.model.input_size),
        accuracy=card.get("accuracy") or {},
    )


@router.get("/v1/model", responses=ERROR_RESPONSES)
async def model_card(predictor: PredictorDep) -> dict[str, Any]:
    """The default model's card: name, version, input size, classes, profile, accuracy."""
    return predictor.model.card


@router.get("/v1/models", response_model=ModelsResponse, responses=ERROR_RESPONSES)
async def list_models(state: StateDep, settings: SettingsDep) -> ModelsResponse:
    """Every served model (the model folder's `<name>.onnx` files) with its card's summary."""
    default = settings.default_model
    return ModelsResponse(
        default=default,
        models=[
            model_info(name, predictor, name == default)
            for name, predictor in state.models.predictors().items()
        ],
        problems=state.models.problems,
    )


@router.post("/v1/models/reload", response_model=ReloadResponse, responses=ERROR_RESPONSES)
async def reload_models(state: StateDep) -> ReloadResponse:
    """Pick up added, replaced and removed model files without a restart (every worker).

    Requests in flight finish on the session they started with.
    """
    report = await anyio.to_thread.run_sync(state.reload_everywhere)
    return ReloadResponse(**asdict(report))
