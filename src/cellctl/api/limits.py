"""The request body limit: a body over ``[api] max_body_bytes`` is answered 413 before it is read."""

from __future__ import annotations

from starlette.datastructures import Headers
from starlette.exceptions import HTTPException
from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send


def body_limit_detail(max_bytes: int) -> str:
    return (
        f"request body larger than {max_bytes} bytes, the limit of this service ([api] max_body_bytes); "
        "the API's bodies are small JSON documents: check what is being sent"
    )


class BodyTooLarge(HTTPException):
    """Raised from the application's ``receive`` at the first byte over the limit; the app renders it as 413."""

    def __init__(self, max_bytes: int) -> None:
        super().__init__(413, detail=body_limit_detail(max_bytes))


class BodySizeLimit:
    """ASGI middleware: no request body over ``max_bytes`` reaches the application.

    A declared Content-Length over the limit is answered 413 before the application runs. A body
    without one (chunked) is counted as it streams in: the chunk that passes the limit raises
    :class:`BodyTooLarge` in the application's ``receive`` (FastAPI passes an HTTPException on and
    its handler answers 413); if it escapes the application before a response started, it is
    answered here.
    """

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = _content_length(scope)
        if declared is not None and declared > self.max_bytes:
            await self._refuse(scope, receive, send)
            return
        received = 0
        started = False

        async def counted_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    raise BodyTooLarge(self.max_bytes)
            return message

        async def tracked_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counted_receive, tracked_send)
        except BodyTooLarge:
            if started:
                raise
            await self._refuse(scope, receive, send)

    async def _refuse(self, scope: Scope, receive: Receive, send: Send) -> None:
        response = JSONResponse({"detail": body_limit_detail(self.max_bytes)}, status_code=413)
        await response(scope, receive, send)


def _content_length(scope: Scope) -> int | None:
    """The declared body length (None: not declared or not a number; the body is then counted as it comes)."""
    value = Headers(scope=scope).get("content-length")
    if value is None or not value.strip().isdigit():
        return None
    return int(value)
