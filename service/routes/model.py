"""The served model's card."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from service.deps import AUTHORISED, PredictorDep
from service.schemas import ERROR_RESPONSES

router = APIRouter(tags=["models"], dependencies=AUTHORISED)


@router.get("/v1/model", responses=ERROR_RESPONSES)
async def model_card(predictor: PredictorDep) -> dict[str, Any]:
    """The model card: name, version, input size, classes, profile, training, accuracy."""
    return predictor.model.card
