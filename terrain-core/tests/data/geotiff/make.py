#!/usr/bin/python3
"""Writes the GeoTIFF/JPEG test variants in this folder from the shared SRTM heights, with GDAL.

Run once with the system Python that has GDAL's bindings (Debian: `apt-get install gdal-bin
python3-gdal`), from anywhere:

    /usr/bin/python3 terrain-core/tests/data/geotiff/make.py [path/to/shared/data]

Every variant is a 64 x 48 crop of srtm/mt_rainier_90m.tif (columns 840.., rows 0..; it holds
voids of -32768) written with another photometric interpretation, CRS, compression or void
sentinel. GDAL's own reading of each file (size, geotransform, linear unit of the CRS, min/max
and sum of the valid samples, nodata value, void count, band checksum) is stored beside them in
gdal_values.json: the tests compare the engine's reader with these, not with numbers of their
own. Nothing here runs at test time.
"""
import array
import json
import os
import sys
import zlib

from osgeo import gdal, osr

gdal.UseExceptions()
HERE = os.path.dirname(os.path.abspath(__file__))
DATA = sys.argv[1] if len(sys.argv) > 1 else os.path.join(HERE, "../../../../../shared/data")
SRC = os.path.join(DATA, "srtm/mt_rainier_90m.tif")
SRCWIN = [840, 0, 64, 48]
VOID = -32768

# User-defined projected CRSs (no EPSG code): GDAL writes ProjectedCSTypeGeoKey = 32767 and
# the projection's parameters as keys.
TMERC_FT = "+proj=tmerc +lat_0=0 +lon_0=-121 +k=0.9996 +x_0=500000 +y_0=0 +datum=WGS84 +units=ft +no_defs"
TMERC_M = "+proj=tmerc +lat_0=0 +lon_0=-121 +k=0.9996 +x_0=500000 +y_0=0 +datum=WGS84 +units=m +no_defs"
ALBERS_M = "+proj=aea +lat_0=23 +lon_0=-96 +lat_1=29.5 +lat_2=45.5 +x_0=0 +y_0=0 +datum=NAD83 +units=m +no_defs"


def path(name):
    return os.path.join(HERE, name)


def crop(name, extra, ot="Int16", nodata=VOID):
    opts = ["-q", "-srcwin", *map(str, SRCWIN), "-ot", ot]
    if nodata is not None:
        opts += ["-a_nodata", str(nodata)]
    gdal.Translate(path(name), SRC, options=opts + extra)


def projected(name, srs, ulx, uly, pixel, extra=()):
    """The crop with another (projected) CRS: the corner and pixel size in that CRS's unit."""
    w, h = SRCWIN[2], SRCWIN[3]
    crop(name, ["-a_srs", srs, "-a_ullr", str(ulx), str(uly), str(ulx + w * pixel),
                str(uly - h * pixel), *extra])


def resentinel(name, src, value):
    """Float32 copy of `src` with its voids set to `value` and no nodata tag."""
    s = gdal.Open(path(src))
    w, h = s.RasterXSize, s.RasterYSize
    a = array.array("h", s.GetRasterBand(1).ReadRaster(buf_type=gdal.GDT_Int16))
    out = array.array("f", (float(value) if v == VOID else float(v) for v in a))
    d = gdal.GetDriverByName("GTiff").Create(path(name), w, h, 1, gdal.GDT_Float32)
    d.SetGeoTransform(s.GetGeoTransform())
    d.SetProjection(s.GetProjection())
    d.GetRasterBand(1).WriteRaster(0, 0, w, h, out.tobytes(), buf_type=gdal.GDT_Float32)
    d = None


def values(name):
    ds = gdal.Open(path(name))
    b = ds.GetRasterBand(1)
    nd = b.GetNoDataValue()
    w, h = ds.RasterXSize, ds.RasterYSize
    raw = array.array("d", b.ReadRaster(buf_type=gdal.GDT_Float64))
    valid = [v for v in raw if nd is None or v != nd]
    srs = ds.GetSpatialRef()
    unit = None
    if srs is not None and srs.IsProjected():
        unit = srs.GetLinearUnits()
    return {
        "file": name,
        "driver": ds.GetDriver().ShortName,
        "size": [w, h],
        "geotransform": list(ds.GetGeoTransform()),
        "projected": bool(srs is not None and srs.IsProjected()),
        "epsg": srs.GetAuthorityCode(None) if srs is not None else None,
        "linear_unit_m": unit,
        "photometric": ds.GetMetadataItem("PHOTOMETRIC", "IMAGE_STRUCTURE") if name.endswith(".tif") else None,
        "compression": ds.GetMetadataItem("COMPRESSION", "IMAGE_STRUCTURE"),
        "nodata": nd,
        "voids": w * h - len(valid),
        "min": min(valid),
        "max": max(valid),
        "sum": sum(valid),
        "checksum": b.Checksum(),
    }


def deflate_flips(name):
    """The verdicts on single-bit flips of the first chunk's Deflate stream (every bit of its
    last 64 bytes, every 97th bit before them): the bits whose
    flip the reference zlib (Python's zlib module: inflate to the end of the stream, Adler-32
    checked) still accepts, and those GDAL reads without an error. GDAL 3.6 stops inflating
    once it has the chunk's bytes, like the `tiff` crate, so it reads some of these damaged
    chunks as numbers; the truth for the tests is zlib's verdict."""
    ds = gdal.Open(path(name))
    b = ds.GetRasterBand(1)
    offset = int(b.GetMetadataItem("BLOCK_OFFSET_0_0", "TIFF"))
    count = int(b.GetMetadataItem("BLOCK_SIZE_0_0", "TIFF"))
    ds = None
    data = bytearray(open(path(name), "rb").read())
    tmp = "/vsimem/flip.tif"
    accepted = []
    every, tail = 97, 64
    bits = list(range(0, (count - tail) * 8, every)) + list(range((count - tail) * 8, count * 8))
    gdal.PushErrorHandler("CPLQuietErrorHandler")
    for bit in bits:
        d = bytearray(data)
        d[offset + bit // 8] ^= 1 << (bit % 8)
        gdal.FileFromMemBuffer(tmp, bytes(d))
        try:
            f = gdal.Open(tmp)
            f.GetRasterBand(1).ReadRaster()
            accepted.append(bit)
        except RuntimeError:
            pass
        f = None
        gdal.Unlink(tmp)
    gdal.PopErrorHandler()
    zlib_ok = []
    for bit in bits:
        d = bytearray(data[offset:offset + count])
        d[bit // 8] ^= 1 << (bit % 8)
        try:
            z = zlib.decompressobj()
            z.decompress(bytes(d))
            if z.eof:
                zlib_ok.append(bit)
        except zlib.error:
            pass
    return {"file": name, "chunk": 0, "offset": offset, "bytes": count,
            "every_nth_bit": every, "tail_bytes": tail, "flips": len(bits),
            "zlib_accepted_bits": zlib_ok, "gdal_accepted": len(accepted)}


def main():
    made = []
    # Item 1: WhiteIsZero (GDAL reads the stored values as they are).
    crop("wiz_int16.tif", ["-co", "PHOTOMETRIC=MINISWHITE"])
    crop("wiz_float32.tif", ["-co", "PHOTOMETRIC=MINISWHITE"], ot="Float32")
    made += ["wiz_int16.tif", "wiz_float32.tif"]
    # Item 2: EPSG:2272 (NAD83 / Pennsylvania South, US survey feet), 300 ft pixels.
    projected("ftus_epsg2272.tif", "EPSG:2272", 2_000_000, 300_000, 300)
    made.append("ftus_epsg2272.tif")
    # Item 3: user-defined transverse Mercator in international feet and in metres; Albers.
    projected("ftintl_user_tmerc.tif", TMERC_FT, 1_900_000, 17_000_000, 300)
    projected("m_user_tmerc.tif", TMERC_M, 580_000, 5_200_000, 90)
    projected("m_user_albers.tif", ALBERS_M, -1_900_000, 2_900_000, 90)
    made += ["ftintl_user_tmerc.tif", "m_user_tmerc.tif", "m_user_albers.tif"]
    # Item 4: one Deflate strip over 32 KiB (no predictor: the tests flip bits of the stream).
    # Its size matters: the `tiff` crate's inflater reads the stream through a 32 KiB buffer and
    # stops when it has the strip's bytes, so the end of a longer stream (the Adler-32) was
    # never checked.
    gdal.Translate(path("deflate_strip.tif"), SRC,
                   options=["-q", "-srcwin", "600", "300", "256", "128", "-a_nodata", str(VOID),
                            "-co", "COMPRESS=DEFLATE", "-co", "ZLEVEL=1", "-co", "BLOCKYSIZE=128"])
    made.append("deflate_strip.tif")
    # Item 5: an 8-bit grey JPEG heightmap (the tests truncate it).
    gdal.Translate(path("grey.jpg"), SRC, options=["-q", "-of", "JPEG", "-srcwin", *map(str, SRCWIN),
                                                   "-ot", "Byte", "-scale", "0", "4400", "1", "255", "-a_nodata", "none",
                                                   "-co", "QUALITY=95", "-co", "WORLDFILE=NO"])
    for extra in ("grey.jpg.aux.xml",):
        if os.path.exists(path(extra)):
            os.remove(path(extra))
    made.append("grey.jpg")
    # Item 8: extreme void sentinels without a nodata tag.
    resentinel("sentinel_9999.tif", "wiz_int16.tif", -9999)
    resentinel("sentinel_f32min.tif", "wiz_int16.tif", -3.4028234663852886e38)
    made += ["sentinel_9999.tif", "sentinel_f32min.tif"]
    for f in os.listdir(HERE):
        if f.endswith(".aux.xml"):
            os.remove(path(f))
    with open(path("gdal_values.json"), "w") as f:
        json.dump({"gdal": gdal.__version__, "variants": [values(n) for n in made],
                   "deflate_flips": deflate_flips("deflate_strip.tif")}, f, indent=1)
        f.write("\n")


if __name__ == "__main__":
    main()
