"""Warp, imported once with difflab's settings: no greeting, no per-module compile messages."""

import warp as wp

wp.config.log_level = wp.LOG_WARNING

__all__ = ["wp"]
