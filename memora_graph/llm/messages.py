"""Multimodal content parts of a chat message (passed through to the server unchanged)."""

from __future__ import annotations

import base64
from typing import Any


def text_part(text: str) -> dict[str, Any]:
    return {"type": "text", "text": text}


def image_part(data: bytes, mime: str = "image/jpeg") -> dict[str, Any]:
    """An image as an OpenAI `image_url` part holding a data: URL."""
    encoded = base64.b64encode(data).decode("ascii")
    return {"type": "image_url", "image_url": {"url": f"data:{mime};base64,{encoded}"}}


def audio_part(data: bytes, fmt: str = "wav") -> dict[str, Any]:
    """Audio as an OpenAI `input_audio` part (base64, format "wav" or "mp3")."""
    return {"type": "input_audio", "input_audio": {"data": base64.b64encode(data).decode("ascii"), "format": fmt}}

