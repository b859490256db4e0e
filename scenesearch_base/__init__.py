"""What every stage shares: atomic writes and reading and writing configs.

This package sits below all stages (``scenes``, ``captioning``, ``encoders``, ``indexes``,
``retrieval``) and imports none of them.
"""
