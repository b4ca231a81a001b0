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


def band_values(b):
    """Void count, min, max and sum of the valid samples of band `b` as GDAL reads them: a
    sample is valid where GDAL's mask band says so (nodata, an internal mask, sparse tiles),
    its value unscaled (GDAL's ReadRaster does not apply the band's scale/offset)."""
    raw = array.array("d", b.ReadRaster(buf_type=gdal.GDT_Float64))
    mask = b.GetMaskBand().ReadRaster(buf_type=gdal.GDT_Byte)
    valid = [v for v, m in zip(raw, mask) if m != 0]
    return {"voids": len(raw) - len(valid), "min": min(valid), "max": max(valid),
            "sum": sum(valid), "checksum": b.Checksum()}


def read_crop(srcwin=SRCWIN):
    """The crop's int16 samples (north row first), size, geotransform and projection."""
    s = gdal.Open(SRC)
    x, y, w, h = srcwin
    a = array.array("h", s.GetRasterBand(1).ReadRaster(x, y, w, h, buf_type=gdal.GDT_Int16))
    gt = list(s.GetGeoTransform())
    gt[0] += x * gt[1]
    gt[3] += y * gt[5]
    return a, w, h, gt, s.GetProjection()


def create(name, w, h, bands, dtype, gt, proj, options):
    d = gdal.GetDriverByName("GTiff").Create(path(name), w, h, bands, dtype, options=options)
    d.SetGeoTransform(gt)
    d.SetProjection(proj)
    return d


def sparse(name, nodata, options, tiled):
    """The crop written with SPARSE_OK=TRUE, only its west half (tiles) or north half (strips):
    the other blocks are never written, so their offset and byte count stay 0 (GDAL reads them
    as nodata, or 0 when the band has none)."""
    a, w, h, gt, proj = read_crop()
    d = create(name, w, h, 1, gdal.GDT_Int16, gt, proj, ["SPARSE_OK=TRUE", *options])
    b = d.GetRasterBand(1)
    if nodata is not None:
        b.SetNoDataValue(nodata)
    cols, rows = (w // 2, h) if tiled else (w, h // 2)
    part = array.array("h", (a[r * w + c] for r in range(rows) for c in range(cols)))
    b.WriteRaster(0, 0, cols, rows, part.tobytes(), buf_type=gdal.GDT_Int16)
    d = None


def nbits(name, n, options):
    """A 61 x 47 crop (rows end inside a byte at any NBITS) quantised to n bits: 900..2000 m to
    0..2^n-1 (rounded), voids to 0."""
    a, w, h, gt, proj = read_crop([840, 0, 61, 47])
    top = (1 << n) - 1
    q = array.array("B", (0 if v == VOID else max(0, min(top, ((v - 900) * top + 550) // 1100)) for v in a))
    d = create(name, w, h, 1, gdal.GDT_Byte, gt, proj, [f"NBITS={n}", *options])
    d.GetRasterBand(1).WriteRaster(0, 0, w, h, q.tobytes(), buf_type=gdal.GDT_Byte)
    d = None


def multiband(name, bands, options):
    """The crop in `bands` bands, band k (from 1) the heights plus 1000 (k - 1) m, voids kept."""
    a, w, h, gt, proj = read_crop()
    d = create(name, w, h, bands, gdal.GDT_Int16, gt, proj, options)
    for k in range(bands):
        b = d.GetRasterBand(k + 1)
        b.SetNoDataValue(VOID)
        v = array.array("h", (x if x == VOID else x + 1000 * k for x in a))
        b.WriteRaster(0, 0, w, h, v.tobytes(), buf_type=gdal.GDT_Int16)
    d = None


def masked(name, options):
    """The crop without a nodata value and with a per-dataset internal mask (a second IFD,
    NewSubfileType 4): masked where the crop has voids and in its 8 x 8 north-west corner."""
    a, w, h, gt, proj = read_crop()
    gdal.SetConfigOption("GDAL_TIFF_INTERNAL_MASK", "YES")
    d = create(name, w, h, 1, gdal.GDT_Int16, gt, proj, options)
    d.GetRasterBand(1).WriteRaster(0, 0, w, h, a.tobytes(), buf_type=gdal.GDT_Int16)
    d.CreateMaskBand(gdal.GMF_PER_DATASET)
    m = array.array("B", (0 if a[r * w + c] == VOID or (r < 8 and c < 8) else 255
                          for r in range(h) for c in range(w)))
    d.GetRasterBand(1).GetMaskBand().WriteRaster(0, 0, w, h, m.tobytes(), buf_type=gdal.GDT_Byte)
    d = None
    gdal.SetConfigOption("GDAL_TIFF_INTERNAL_MASK", None)


def values(name):
    ds = gdal.Open(path(name))
    b = ds.GetRasterBand(1)
    nd = b.GetNoDataValue()
    w, h = ds.RasterXSize, ds.RasterYSize
    one = band_values(b)
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
        **one,
        "bands": ds.RasterCount,
        "per_band": [band_values(ds.GetRasterBand(k + 1)) for k in range(ds.RasterCount)],
        "nbits": b.GetMetadataItem("NBITS", "IMAGE_STRUCTURE"),
        "scale": b.GetScale(),
        "offset": b.GetOffset(),
        "mask_flags": b.GetMaskFlags(),
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
    # Issue 15, item 6 and the sparse/NBITS/compression/band bullet.
    # Sparse tiles and strips: byte count 0, read as nodata (or 0 without a nodata value).
    sparse("sparse_tiled_deflate.tif", VOID, ["TILED=YES", "BLOCKXSIZE=16", "BLOCKYSIZE=16",
                                              "COMPRESS=DEFLATE"], True)
    sparse("sparse_strips_nonodata.tif", None, ["BLOCKYSIZE=8"], False)
    made += ["sparse_tiled_deflate.tif", "sparse_strips_nonodata.tif"]
    # 1- to 7-bit samples (bit-packed rows).
    nbits("nbits1.tif", 1, [])
    nbits("nbits3_tiled_deflate.tif", 3, ["TILED=YES", "BLOCKXSIZE=16", "BLOCKYSIZE=16",
                                          "COMPRESS=DEFLATE"])
    nbits("nbits7_lzw.tif", 7, ["COMPRESS=LZW", "BLOCKYSIZE=10"])
    made += ["nbits1.tif", "nbits3_tiled_deflate.tif", "nbits7_lzw.tif"]
    # ZSTD (compression 50000) with predictors 1, 2 and 3, both byte orders.
    crop("zstd_p1.tif", ["-co", "COMPRESS=ZSTD"])
    crop("zstd_p2_tiled.tif", ["-co", "COMPRESS=ZSTD", "-co", "PREDICTOR=2", "-co", "TILED=YES",
                               "-co", "BLOCKXSIZE=16", "-co", "BLOCKYSIZE=16"])
    crop("zstd_p2_be.tif", ["-co", "COMPRESS=ZSTD", "-co", "PREDICTOR=2", "-co", "ENDIANNESS=BIG",
                            "-co", "BLOCKYSIZE=16"])
    crop("zstd_p3_f32.tif", ["-co", "COMPRESS=ZSTD", "-co", "PREDICTOR=3"], ot="Float32")
    # (No big-endian file with predictor 3: GDAL 3.6 reads its own such files, float32 or
    # float64, back as garbage, so there is no truth to compare with.)
    crop("zstd_p3_f64.tif", ["-co", "COMPRESS=ZSTD", "-co", "PREDICTOR=3", "-co",
                             "BLOCKYSIZE=16"], ot="Float64")
    made += ["zstd_p1.tif", "zstd_p2_tiled.tif", "zstd_p2_be.tif", "zstd_p3_f32.tif",
             "zstd_p3_f64.tif"]
    # Compressions that are refused, by name.
    crop("lerc.tif", ["-co", "COMPRESS=LERC"])
    crop("lzma.tif", ["-co", "COMPRESS=LZMA"])
    # WebP takes 8-bit RGB(A) only: the crop scaled to bytes, three times.
    gdal.Translate(path("webp_rgb.tif"), SRC,
                   options=["-q", "-srcwin", *map(str, SRCWIN), "-ot", "Byte", "-scale", "0",
                            "4400", "0", "255", "-a_nodata", "none", "-b", "1", "-b", "1", "-b", "1",
                            "-co", "COMPRESS=WEBP", "-co", "WEBP_LOSSLESS=TRUE"])
    made += ["lerc.tif", "lzma.tif", "webp_rgb.tif"]
    # Several bands: pixel- and band-interleaved.
    multiband("bands3_pixel.tif", 3, ["INTERLEAVE=PIXEL", "COMPRESS=DEFLATE"])
    multiband("bands2_band.tif", 2, ["INTERLEAVE=BAND", "COMPRESS=LZW", "TILED=YES",
                                     "BLOCKXSIZE=16", "BLOCKYSIZE=16"])
    made += ["bands3_pixel.tif", "bands2_band.tif"]
    # GDAL band scale and offset (metadata tag 42112).
    crop("scaled.tif", ["-a_scale", "0.5", "-a_offset", "100"])
    made.append("scaled.tif")
    # An internal per-dataset mask.
    masked("mask_internal.tif", ["COMPRESS=DEFLATE"])
    made.append("mask_internal.tif")
    for f in os.listdir(HERE):
        if f.endswith(".aux.xml"):
            os.remove(path(f))
    with open(path("gdal_values.json"), "w") as f:
        json.dump({"gdal": gdal.__version__, "variants": [values(n) for n in made],
                   "deflate_flips": deflate_flips("deflate_strip.tif")}, f, indent=1)
        f.write("\n")


if __name__ == "__main__":
    main()
