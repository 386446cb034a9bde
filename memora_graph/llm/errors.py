"""What goes wrong between us and a model, as exception classes.

Transport failures are `ModelServerError`s; each kind a user must act on differently has its own
subclass, and every message names the URL and the model: the server is down, the model is not
served there, the key is refused, the request timed out, the prompt is over the context window,
or the server kept rate-limiting after the retries."""

from __future__ import annotations

from memora_graph.errors import MemoraError


class ModelError(MemoraError):
    """Base class of everything that goes wrong between us and a model."""


class UnknownBackendError(ModelError):
    """A backend name that is not registered; the message lists the registered ones."""


class BackendOptionsError(ModelError):
    """Options that do not validate for the chosen backend; the message names the option."""


class ModelUnavailableError(ModelError):
    """No model can serve this role: the offline backend, or an optional extra not installed."""


class ModelServerError(ModelError):
    """The server could not be reached or answered with an error; the message names the URL."""

    def __init__(self, message: str, *, url: str, status: int | None = None, body: str | None = None,
                 model: str | None = None):
        super().__init__(message)
        self.url = url
        self.status = status
        self.body = body
        self.model = model


class ModelServerDownError(ModelServerError):
    """Nothing answers at the URL (connection refused or reset, DNS failure)."""


class ModelNotServedError(ModelServerError):
    """The server answers, but does not serve the model asked for (or the URL has no such route)."""


class ModelAuthError(ModelServerError):
    """The server refused the API key (HTTP 401 / 403)."""


class ModelTimeoutError(ModelServerError):
    """No reply within timeout_s, after the retries."""


class ModelContextLengthError(ModelServerError):
    """The prompt (plus max_tokens) is longer than the model's context window."""


class ModelRateLimitedError(ModelServerError):
    """HTTP 429 (or 503 overloaded) on every attempt."""


class ModelReplyError(ModelError):
    """The model answered, but not with what was asked for, even after one repair turn."""

    def __init__(self, message: str, *, raw_reply: str, role: str, attempts: list[str] | None = None):
        super().__init__(message)
        self.raw_reply = raw_reply
        self.role = role
        self.attempts = attempts or [raw_reply]
