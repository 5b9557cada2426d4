"""The body limit middleware on its own: it answers 413 itself when the application does not."""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Any

import httpx

from cellctl.api.limits import BodySizeLimit


class EchoLength:
    """A bare ASGI app that reads the whole body (no framework to turn an error into a response)."""

    def __init__(self) -> None:
        self.called = 0

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        self.called += 1
        size, more = 0, True
        while more:
            message = await receive()
            size += len(message.get("body", b""))
            more = message.get("more_body", False)
        await send({"type": "http.response.start", "status": 200, "headers": [(b"content-type", b"text/plain")]})
        await send({"type": "http.response.body", "body": str(size).encode()})


async def chunks(n: int, size: int) -> AsyncIterator[bytes]:
    for _ in range(n):
        yield b"x" * size


async def test_the_limit_answers_413_whether_or_not_the_application_reads_the_body() -> None:
    app = EchoLength()
    transport = httpx.ASGITransport(app=BodySizeLimit(app, max_bytes=1000))
    async with httpx.AsyncClient(transport=transport, base_url="http://cell") as client:
        assert (await client.post("/", content=b"x" * 1000)).text == "1000"
        declared = await client.post("/", content=b"x" * 1001)
        assert declared.status_code == 413 and "max_body_bytes" in declared.json()["detail"]
        assert app.called == 1  # refused on its Content-Length: the application never ran
        streamed = await client.post("/", content=chunks(5, 300))
        assert streamed.status_code == 413 and "1000 bytes" in streamed.json()["detail"]
        assert (await client.post("/", content=chunks(3, 300))).text == "900"
