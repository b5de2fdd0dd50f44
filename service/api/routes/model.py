"""The served models: the default model's card, the list of models, reloading the folder."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

import anyio
from fastapi import APIRouter, Response

from service.api.deps import AUTHORISED, PredictorDep, SettingsDep, StateDep
from service.api.errors import ApiError
from service.api.schemas import ERROR_RESPONSES, ModelInfo, ModelsResponse, ReloadResponse
from service.pipeline.model import ModelLoadError, read_texture_png, training_of
from service.pipeline.model_cache import ModelFile

router = APIRouter(tags=["models"], dependencies=AUTHORISED)


def model_info(file: ModelFile, default: bool, loaded: bool) -> ModelInfo:
    """A served model's summary, from its card (its graph loaded or not)."""
    card = file.card
    profile = card.get("profile")
    return ModelInfo(
        name=file.name,
        default=default,
        loaded=loaded,
        card_name=str(card["name"]),  # the card's; a copied file keeps it
        version=card.get("version"),
        profile=profile.get("name") if isinstance(profile, dict) else profile,
        input=list(file.input_size or ()),
        accuracy=card.get("accuracy") or {},
        training=training_of(card),
    )


@router.get("/v1/model", responses=ERROR_RESPONSES)
async def model_card(predictor: PredictorDep) -> dict[str, Any]:
    """The default model's card: name, version, input size, classes, profile, accuracy."""
    return predictor.model.card


@router.get("/v1/models", response_model=ModelsResponse, responses=ERROR_RESPONSES)
async def list_models(state: StateDep, settings: SettingsDep) -> ModelsResponse:
    """Every served model (the model folder's `<name>.onnx` files) with its card's summary
    and whether its graph is loaded in the worker that answers."""
    default, cache = settings.default_model, state.models.cache
    return ModelsResponse(
        default=default,
        models=[
            model_info(file, name == default, cache.is_loaded(file))
            for name, file in state.models.entries().items()
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


@router.get(
    "/v1/models/{name}/texture",
    response_class=Response,
    responses={
        **ERROR_RESPONSES,
        200: {"content": {"image/png": {}}, "description": "The object's front-on picture."},
        404: {"description": "No model of that name, or it carries no picture."},
    },
)
async def model_texture(name: str, state: StateDep) -> Response:
    """The front-on picture of the served model `name`'s object (PNG, as embedded in its
    graph; the web page draws it), read without loading the graph."""
    file = state.models.entries().get(name)
    if file is None:
        known = ", ".join(state.models.entries()) or "none"
        raise ApiError(404, "model_not_found", f"no model named {name!r}; served: {known}")
    try:
        found = await anyio.to_thread.run_sync(read_texture_png, file.path)
    except ModelLoadError as exc:
        raise ApiError(503, "model_unavailable", str(exc)) from None
    if found is None:
        raise ApiError(404, "no_texture", f"model {name!r} carries no picture of its object")
    return Response(found[0], media_type="image/png", headers={"Cache-Control": "no-cache"})
