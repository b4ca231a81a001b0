#!/usr/bin/env python3
"""A TCP proxy that adds a fixed latency to every request: for measuring a store streamed
over HTTP with a slow link (README, "Stores on object storage and HTTP"; bench/ooc/README.md).

    python3 scripts/delay_proxy.py LISTEN_PORT TARGET_PORT [DELAY_MS]

Listens on 127.0.0.1:LISTEN_PORT and forwards each connection to 127.0.0.1:TARGET_PORT (nginx
serving a store folder, say); the bytes of each request from the client are held DELAY_MS
(default 50) before they are forwarded, so every request (a range GET of a block) takes at
least that much longer, as over a link with that round-trip time. Standard library only.
"""

import asyncio
import sys


async def pipe(reader, writer, delay_s):
    try:
        while True:
            data = await reader.read(65536)
            if not data:
                break
            if delay_s:
                await asyncio.sleep(delay_s)
            writer.write(data)
            await writer.drain()
    except (ConnectionError, asyncio.CancelledError):
        pass
    finally:
        try:
            writer.close()
        except Exception:
            pass


async def main():
    listen, target = int(sys.argv[1]), int(sys.argv[2])
    delay_s = (float(sys.argv[3]) if len(sys.argv) > 3 else 50.0) / 1000.0

    async def handle(client_r, client_w):
        try:
            server_r, server_w = await asyncio.open_connection("127.0.0.1", target)
        except OSError:
            client_w.close()
            return
        await asyncio.gather(
            pipe(client_r, server_w, delay_s), pipe(server_r, client_w, 0.0)
        )

    server = await asyncio.start_server(handle, "127.0.0.1", listen)
    async with server:
        await server.serve_forever()


if __name__ == "__main__":
    asyncio.run(main())
