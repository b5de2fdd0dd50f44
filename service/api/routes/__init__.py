"""One APIRouter module per concern; `service.app.ROUTERS` lists the ones served."""
