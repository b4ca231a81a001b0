#!/usr/bin/env python3
"""A large DEM of real terrain for the tileset benchmarks: a real SRTM grid from
../shared/data mirror-tiled (reflected at every edge, so the surface stays continuous) into
an N x N little-endian int16 raw grid, north row first, voids kept as -32768. Every sample's
neighbourhood is real terrain, so the per-sample roughness that a TIN's triangle count and
the tiles' cost follow is a real DEM's, at any size (bench/mesh/README.md, "The 16385^2
tileset on real terrain").

    mirror_dem.py N OUT.i16 --hgt N42E001.hgt N41E001.hgt   # .hgt tiles stacked north to south
    mirror_dem.py N OUT.i16 --tif mt_everest_90m.tif         # uncompressed tiled int16 GeoTIFF

Then: terrain bake OUT.i16 --format raw --raw NxN:i16 --nodata -32768 --spacing M --no-pvs
--no-dss -o STORE. Pure Python (no numpy): about 20 s for N = 16385.
"""
import array
import struct
import sys


def hgt(path):
    a = array.array('h')
    with open(path, 'rb') as f:
        a.frombytes(f.read())
    if sys.byteorder == 'little':
        a.byteswap()  # .hgt is big-endian
    side = int(round(len(a) ** 0.5))
    return [a[j * side:(j + 1) * side] for j in range(side)]


def tif(path):
    with open(path, 'rb') as f:
        b = f.read()
    bo = '<' if b[:2] == b'II' else '>'
    off = struct.unpack(bo + 'I', b[4:8])[0]
    tags = {}
    for k in range(struct.unpack(bo + 'H', b[off:off + 2])[0]):
        e = off + 2 + 12 * k
        tag, typ, cnt = struct.unpack(bo + 'HHI', b[e:e + 8])
        if typ == 3 and cnt == 1:
            val = struct.unpack(bo + 'H', b[e + 8:e + 10])[0]
        else:
            val = struct.unpack(bo + 'I', b[e + 8:e + 12])[0]
        tags[tag] = (cnt, val)
    if tags[259][1] != 1 or tags[258][1] != 16 or 322 not in tags:
        sys.exit(f'{path}: only uncompressed, tiled, 16-bit GeoTIFFs are read here')
    w, h, tw, th = (tags[t][1] for t in (256, 257, 322, 323))
    cnt, at = tags[324]
    offsets = struct.unpack(bo + 'I' * cnt, b[at:at + 4 * cnt]) if cnt > 1 else (at,)
    across = (w + tw - 1) // tw
    rows = [array.array('h', bytes(2 * w)) for _ in range(h)]
    for t, o in enumerate(offsets):
        r0, c0 = (t // across) * th, (t % across) * tw
        tile = array.array('h')
        tile.frombytes(b[o:o + 2 * tw * th])
        if (bo == '>') == (sys.byteorder == 'little'):
            tile.byteswap()
        for r in range(min(th, h - r0)):
            n = min(tw, w - c0)
            rows[r0 + r][c0:c0 + n] = tile[r * tw:r * tw + n]
    return rows


def mirror(k, n):
    p = 2 * (n - 1)
    k %= p
    return k if k < n else p - k


def main():
    n, out, kind, paths = int(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4:]
    if kind == '--hgt':
        rows = []
        for p in paths:  # stacked north to south; adjacent tiles share a row
            tile = hgt(p)
            rows.extend(tile if not rows else tile[1:])
    elif kind == '--tif':
        rows = tif(paths[0])
    else:
        sys.exit(__doc__)
    h, w = len(rows), len(rows[0])
    cols = [mirror(i, w) for i in range(n)]
    with open(out, 'wb') as f:
        for j in range(n):
            r = rows[mirror(j, h)]
            a = array.array('h', (r[c] for c in cols))
            if sys.byteorder == 'big':
                a.byteswap()
            f.write(a.tobytes())


if __name__ == '__main__':
    main()
