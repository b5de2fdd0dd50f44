"""The web page at `/` (plain HTML + JavaScript from `service/static/`) and the OpenAPI pages
`/docs` and `/redoc` with their Swagger UI / ReDoc assets served from the `fastapi-offline`
package instead of a CDN: nothing the pages load comes from another host.

The app must be created with `docs_url=None, redoc_url=None`; `install(app)` then adds the
page, the two static mounts and the self-hosted docs pages (FastAPI's documented way:
`get_swagger_ui_html` / `get_redoc_html` with asset URLs of our own).
"""

from __future__ import annotations

from pathlib import Path

import fastapi_offline
from fastapi import FastAPI
from fastapi.openapi.docs import (
    get_redoc_html,
    get_swagger_ui_html,
    get_swagger_ui_oauth2_redirect_html,
)
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles

STATIC = Path(__file__).resolve().parents[2] / "static"
DOCS_ASSETS = Path(fastapi_offline.__file__).resolve().parent / "static"
PAGE_URL, DOCS_ASSETS_URL = "/static", "/docs-assets"
#: The browser itself refuses anything from another host (ReDoc's bundle, for one, would
#: fetch its footer logo from a CDN); inline scripts/styles are the docs pages' own.
CSP = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data: blob:; "
    "style-src 'self' 'unsafe-inline'; script-src 'self' 'unsafe-inline'; "
    "worker-src 'self' blob:; connect-src 'self'; font-src 'self' data:"
}


def _local_only(page: HTMLResponse) -> HTMLResponse:
    page.headers.update(CSP)
    return page


def install(app: FastAPI) -> None:
    """Add `/`, `/static/*`, `/docs`, `/redoc` and their assets to `app`."""
    app.mount(PAGE_URL, StaticFiles(directory=STATIC), name="static")
    app.mount(DOCS_ASSETS_URL, StaticFiles(directory=DOCS_ASSETS), name="docs-assets")
    openapi_url = app.openapi_url or "/openapi.json"
    redirect_url = app.swagger_ui_oauth2_redirect_url or "/docs/oauth2-redirect"
    favicon = f"{DOCS_ASSETS_URL}/favicon.png"

    @app.get("/", include_in_schema=False)
    async def page() -> FileResponse:
        """The web page: photos or the webcam in, the model's answer drawn."""
        return FileResponse(STATIC / "index.html", media_type="text/html", headers=CSP)

    @app.get("/docs", include_in_schema=False)
    async def swagger_ui() -> HTMLResponse:
        return _local_only(
            get_swagger_ui_html(
                openapi_url=openapi_url,
                title=f"{app.title} - Swagger UI",
                oauth2_redirect_url=redirect_url,
                swagger_js_url=f"{DOCS_ASSETS_URL}/swagger-ui-bundle.js",
                swagger_css_url=f"{DOCS_ASSETS_URL}/swagger-ui.css",
                swagger_favicon_url=favicon,
                # no "valid" badge fetched from validator.swagger.io
                swagger_ui_parameters={**(app.swagger_ui_parameters or {}), "validatorUrl": None},
            )
        )

    @app.get(redirect_url, include_in_schema=False)
    async def swagger_ui_redirect() -> HTMLResponse:
        return get_swagger_ui_oauth2_redirect_html()

    @app.get("/redoc", include_in_schema=False)
    async def redoc() -> HTMLResponse:
        return _local_only(
            get_redoc_html(
                openapi_url=openapi_url,
                title=f"{app.title} - ReDoc",
                redoc_js_url=f"{DOCS_ASSETS_URL}/redoc.standalone.js",
                redoc_favicon_url=favicon,
                with_google_fonts=False,
            )
        )
