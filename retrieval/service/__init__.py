"""HTTP API and web page over an index directory (``scenesearch serve``).

Names are imported on first use, so that reading :class:`ServiceLimits` (the CLI's defaults) does
not load the web framework.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from retrieval.service.app import create_app
    from retrieval.service.limits import ServiceLimits
    from retrieval.service.server import ListenError, listen_sockets, serve, server_config, serving_in_thread

__all__ = ["ListenError", "ServiceLimits", "create_app", "listen_sockets", "serve", "server_config",
           "serving_in_thread"]

_HOMES = {"create_app": "app", "ServiceLimits": "limits", "serve": "server", "server_config": "server",
          "serving_in_thread": "server", "ListenError": "server", "listen_sockets": "server"}


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(f"retrieval.service.{_HOMES[name]}"), name)
