"""The interactive API docs, ``/docs`` (Swagger UI) and ``/redoc``, served with no network.

FastAPI's own docs pages load Swagger UI and ReDoc from a CDN. These load them from the service: the
scripts and styles come from the installed ``fastapi_offline`` package (its ``static`` folder), mounted at
``/docs-assets``. Without that package both pages say how to get it and link the OpenAPI schema.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles


def docs_assets_dir() -> Path | None:
    """The folder of Swagger UI's and ReDoc's scripts in the installed ``fastapi_offline`` package, or None."""
    import importlib.util

    spec = importlib.util.find_spec("fastapi_offline")
    if spec is None or spec.origin is None:
        return None
    folder = Path(spec.origin).parent / "static"
    return folder if (folder / "swagger-ui-bundle.js").is_file() else None


def add_docs(app: FastAPI) -> None:
    """``/docs`` (Swagger UI) and ``/redoc`` with their scripts served from this service, so they work with no
    network; without the assets both pages say how to get them and link the OpenAPI schema."""
    from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html

    assets = docs_assets_dir()
    if assets is not None:
        app.mount("/docs-assets", StaticFiles(directory=assets), name="docs-assets")

    def missing(name: str) -> HTMLResponse:
        return HTMLResponse(f"<!doctype html><title>{name}</title><p>{name} needs the package fastapi-offline "
                            "(<code>pip install fastapi-offline</code>), whose files it serves locally. The API's "
                            "schema: <a href='/openapi.json'>/openapi.json</a>.</p>")

    @app.get("/docs", include_in_schema=False, response_model=None)
    def swagger() -> HTMLResponse:
        if assets is None:
            return missing("Swagger UI")
        return get_swagger_ui_html(openapi_url="/openapi.json", title="scenesearch API",
                                   swagger_js_url="/docs-assets/swagger-ui-bundle.js",
                                   swagger_css_url="/docs-assets/swagger-ui.css",
                                   swagger_favicon_url="/docs-assets/favicon.png")

    @app.get("/redoc", include_in_schema=False, response_model=None)
    def redoc() -> HTMLResponse:
        if assets is None:
            return missing("ReDoc")
        return get_redoc_html(openapi_url="/openapi.json", title="scenesearch API",
                              redoc_js_url="/docs-assets/redoc.standalone.js",
                              redoc_favicon_url="/docs-assets/favicon.png", with_google_fonts=False)
