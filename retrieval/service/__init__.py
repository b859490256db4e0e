"""HTTP API and web page over an index directory (``scenesearch serve``)."""

from retrieval.service.app import ServiceLimits, create_app

__all__ = ["ServiceLimits", "create_app"]
