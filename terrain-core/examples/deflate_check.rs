//! What the Deflate check (every strip or tile inflated once more to its Adler-32) costs a
//! GeoTIFF load: the same grid stored with Deflate and uncompressed, each loaded by
//! `dem::load` and decoded by the `tiff` crate alone, interleaved, medians of N runs.
//!
//! ```sh
//! gdal_translate -co COMPRESS=DEFLATE -co TILED=YES ../shared/data/srtm/mt_everest_90m.tif /tmp/d.tif
//! gdal_translate -co TILED=YES ../shared/data/srtm/mt_everest_90m.tif /tmp/p.tif
//! cargo run --release -p terrain-core --example deflate_check -- /tmp/d.tif /tmp/p.tif 15
//! ```
//!
//! `load` minus the decode alone is what the reader adds (void mask and fill, flipping, and for
//! Deflate the check); the difference of that between the two files is the check's cost.

use std::time::Instant;

use terrain_core::dem::{LoadOptions, load};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn decode_only(path: &str) -> usize {
    let file = std::fs::File::open(path).expect("open");
    let mut dec = tiff::decoder::Decoder::new(std::io::BufReader::new(file)).expect("TIFF");
    match dec.read_image().expect("decode") {
        tiff::decoder::DecodingResult::I16(v) => v.len(),
        _ => 0,
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let [_, deflate, plain, rest @ ..] = args.as_slice() else {
        eprintln!("usage: deflate_check DEFLATE.tif UNCOMPRESSED.tif [RUNS]");
        std::process::exit(2);
    };
    let runs: usize = rest.first().and_then(|r| r.parse().ok()).unwrap_or(15);
    let time = |f: &dyn Fn()| {
        let t = Instant::now();
        f();
        t.elapsed().as_secs_f64() * 1e3
    };
    let (mut ld, mut lp, mut dd, mut dp) = (vec![], vec![], vec![], vec![]);
    for _ in 0..runs {
        ld.push(time(&|| drop(load(deflate, &LoadOptions::default()).expect("load"))));
        lp.push(time(&|| drop(load(plain, &LoadOptions::default()).expect("load"))));
        dd.push(time(&|| {
            std::hint::black_box(decode_only(deflate));
        }));
        dp.push(time(&|| {
            std::hint::black_box(decode_only(plain));
        }));
    }
    let (ld, lp, dd, dp) = (median(ld), median(lp), median(dd), median(dp));
    println!(
        "medians of {runs} runs, ms: load deflate {ld:.1}, load plain {lp:.1}, decode deflate {dd:.1}, decode plain {dp:.1}"
    );
    println!(
        "check ~ (load - decode) deflate - (load - decode) plain = {:.1} ms ({:.0} % of the Deflate load)",
        (ld - dd) - (lp - dp),
        100.0 * ((ld - dd) - (lp - dp)) / ld
    );
}
