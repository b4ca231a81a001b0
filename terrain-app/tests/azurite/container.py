#!/usr/bin/env python3
"""Creates a blob container on Azurite (the Azure Storage emulator) for the az:// store test
of terrain-app/tests/remote_store.rs: one Create Container request signed with the emulator's
well-known account key (Shared Key authorization). Standard library only.

    python3 terrain-app/tests/azurite/container.py PORT CONTAINER
"""

import base64
import email.utils
import hashlib
import hmac
import sys
import urllib.request

# Azurite's documented development account and key (public, the emulator's only account).
ACCOUNT = "devstoreaccount1"
KEY = "Eby8vdM02xNOcqFlqUwJPLlmEtlCDXJ1OUzFT50uSRZ6IFsuFq2UVErCz4I6tq/K1SZFPTOtr/KBHBeksoGMGw=="
VERSION = "2021-08-06"


def main():
    port, container = sys.argv[1], sys.argv[2]
    date = email.utils.formatdate(usegmt=True)
    # VERB, eleven empty standard headers, the x-ms- headers, the resource (path-style URL).
    to_sign = (
        "PUT\n" + "\n" * 11 + f"x-ms-date:{date}\nx-ms-version:{VERSION}\n"
        f"/{ACCOUNT}/{ACCOUNT}/{container}\nrestype:container"
    )
    mac = hmac.new(base64.b64decode(KEY), to_sign.encode(), hashlib.sha256).digest()
    request = urllib.request.Request(
        f"http://127.0.0.1:{port}/{ACCOUNT}/{container}?restype=container",
        method="PUT",
        headers={
            "x-ms-date": date,
            "x-ms-version": VERSION,
            "Authorization": f"SharedKey {ACCOUNT}:{base64.b64encode(mac).decode()}",
            "Content-Length": "0",
        },
    )
    with urllib.request.urlopen(request, timeout=30) as reply:
        print(reply.status)


if __name__ == "__main__":
    main()
