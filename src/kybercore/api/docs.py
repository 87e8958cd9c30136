"""``/docs`` (Swagger UI) and ``/redoc`` (ReDoc): the API described by ``/openapi.json``,
readable with no network but this server's.

FastAPI's own pages load their scripts from a CDN and start them with an inline script;
KyberCore's Content-Security-Policy (rightly) blocks both. Here the assets come from the
``fastapi-offline`` package (Swagger UI and ReDoc's dist files; only its files are used),
under ``/docs/assets``, and the start-up script is a file of its own. The two pages get a
policy of their own (:data:`~kybercore.api.security.DOCS_CONTENT_SECURITY_POLICY`):
scripts still only from here, styles set at run time allowed.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path
from typing import Final

from fastapi import APIRouter, FastAPI
from fastapi.responses import HTMLResponse, Response
from fastapi.staticfiles import StaticFiles

from kybercore.api.security import DOCS_CONTENT_SECURITY_POLICY

ASSETS_URL: Final = "/docs/assets"
_HEADERS: Final = {"Content-Security-Policy": DOCS_CONTENT_SECURITY_POLICY}

_SWAGGER_PAGE: Final = f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>KyberCore API</title>
<link rel="stylesheet" href="{ASSETS_URL}/swagger-ui.css">
<link rel="icon" href="{ASSETS_URL}/favicon.png">
</head>
<body>
<div id="swagger-ui"></div>
<script src="{ASSETS_URL}/swagger-ui-bundle.js"></script>
<script src="/docs/start.js"></script>
</body>
</html>
"""

# No validatorUrl: Swagger UI would otherwise fetch a badge from the internet.
_SWAGGER_START: Final = """window.ui = SwaggerUIBundle({
  url: "/openapi.json",
  dom_id: "#swagger-ui",
  layout: "BaseLayout",
  deepLinking: true,
  showExtensions: true,
  showCommonExtensions: true,
  validatorUrl: null,
  presets: [SwaggerUIBundle.presets.apis, SwaggerUIBundle.SwaggerUIStandalonePreset],
});
"""

_REDOC_PAGE: Final = f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>KyberCore API</title>
<link rel="icon" href="{ASSETS_URL}/favicon.png">
</head>
<body>
<redoc spec-url="/openapi.json"></redoc>
<script src="{ASSETS_URL}/redoc.standalone.js"></script>
</body>
</html>
"""

router = APIRouter(include_in_schema=False)


@router.get("/docs")
async def swagger_ui() -> Response:
    """Swagger UI: every operation, with "Try it out"."""
    return HTMLResponse(_SWAGGER_PAGE, headers=_HEADERS)


@router.get("/docs/start.js")
async def swagger_ui_start() -> Response:
    """The script that starts Swagger UI on ``/openapi.json``."""
    return Response(_SWAGGER_START, media_type="text/javascript")


@router.get("/redoc")
async def redoc() -> Response:
    """ReDoc: the same API as one long page."""
    return HTMLResponse(_REDOC_PAGE, headers=_HEADERS)


def add_docs(app: FastAPI) -> None:
    """Serve ``/docs`` and ``/redoc`` with their assets (the app has FastAPI's own off)."""
    app.include_router(router)
    assets = Path(str(files("fastapi_offline") / "static"))
    app.mount(ASSETS_URL, StaticFiles(directory=assets), name="docs-assets")
