"""A minimal Foxglove WebSocket protocol client, written from the published protocol document
(github.com/foxglove/ws-protocol, docs/spec.md, subprotocol ``foxglove.websocket.v1``), not from
the server's code. The foxglove-sdk server names the same protocol ``foxglove.sdk.v1`` (Foxglove's
stated stance: identical to ``foxglove.websocket.v1`` but for the name; its handshake refuses the
old name), so the client offers both and accepts either. It reads ``serverInfo`` and
``advertise`` (JSON text messages), sends ``subscribe``, and decodes binary Message Data
frames (opcode 0x01, uint32 subscription id, uint64 receive timestamp ns, little-endian, then
the payload)."""

from __future__ import annotations

import asyncio
import json
import struct
import time

import websockets

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01


async def _collect(url: str, topics: list[str], seconds: float, settle_s: float) -> dict:
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS, max_size=None) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        info: dict = {}
        channels: dict[str, dict] = {}
        deadline = time.monotonic() + 10.0
        while not set(topics) <= set(channels) and time.monotonic() < deadline:
            raw = await asyncio.wait_for(ws.recv(), timeout=10.0)
            if isinstance(raw, bytes):
                continue
            msg = json.loads(raw)
            if msg["op"] == "serverInfo":
                info = msg
            elif msg["op"] == "advertise":
                for ch in msg["channels"]:
                    channels[ch["topic"]] = ch
        missing = set(topics) - set(channels)
        assert not missing, f"not advertised: {missing}"
        subs = {i: channels[t] for i, t in enumerate(topics)}
        await ws.send(
            json.dumps(
                {
                    "op": "subscribe",
                    "subscriptions": [{"id": i, "channelId": ch["id"]} for i, ch in subs.items()],
                }
            )
        )
        received: dict[str, list] = {t: [] for t in topics}
        start = time.monotonic() + settle_s
        end = start + seconds
        while (now := time.monotonic()) < end:
            try:
                raw = await asyncio.wait_for(ws.recv(), timeout=end - now)
            except TimeoutError:
                break
            if not isinstance(raw, bytes) or raw[0] != MESSAGE_DATA:
                continue
            sub_id, stamp_ns = struct.unpack_from("<IQ", raw, 1)
            if time.monotonic() < start:
                continue  # subscription settling
            ch = subs[sub_id]
            payload = raw[13:]
            received[ch["topic"]].append(
                (stamp_ns, json.loads(payload) if ch["encoding"] == "json" else payload)
            )
        return {"info": info, "channels": channels, "received": received, "seconds": seconds}


def collect(url: str, topics: list[str], seconds: float, settle_s: float = 0.3) -> dict:
    """Connect, subscribe to ``topics`` and return what arrived over ``seconds``."""
    return asyncio.run(_collect(url, topics, seconds, settle_s))
