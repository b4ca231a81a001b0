//! The papers whose result tables are not regenerated yet (the geomorphing article, the
//! entropy paper): their documents list each table with the paper's numbers and the reason
//! ours is missing.

use super::doc::{PaperDoc, Section, Table, num, text};

/// The geomorphing article (Wagner 2003): Table 1 not produced yet.
pub(crate) fn geomorph() -> PaperDoc {
    let mut t1 = Section::missing(
        "Table 1",
        "Frame rates at different scene setups and LOD systems",
        "The engine has no CPU-morphing path (the article's 'software morphing': vertices \
         morphed on the CPU and sent over the bus each frame) and no multi-material 'full \
         scene' setup in the benchmark; static geo-mipmapping is geomorph with tweening off, \
         which the benchmark measures only for popping (`vertex_jump_no_morph_m`), not as a \
         timed method. Needed: a `geomorph-static` and a `geomorph-cpu` method variant in \
         terrain-app's registry, then a `terrain bench` run of the three.",
    );
    let mut p = Table::new(
        "Athlon-1300, GeForce3.",
        &["Scene", "Static LOD", "Software Morphing", "Hardware Morphing"],
    );
    p.rows.push(vec![text("Minimum scene"), num(504.0, 0), num(312.0, 0), num(501.0, 0)]);
    p.rows.push(vec![text("Full scene"), num(231.0, 0), num(205.0, 0), num(230.0, 0)]);
    t1.paper = Some(p);
    PaperDoc {
        key: "geomorph".into(),
        title:
            "Wagner 2003, \"Terrain Geomorphing in the Vertex Shader\" (the geomorphing article)"
                .into(),
        differences: vec!["No table produced yet (see below).".into()],
        commands: Vec::new(),
        load: Vec::new(),
        quick: false,
        sections: vec![t1],
    }
}

/// The entropy paper (Chen 2018): Tables 1-2 not produced yet.
pub(crate) fn entropy() -> PaperDoc {
    let mut t1 = Section::missing(
        "Table 1",
        "Performance against the entropy threshold E0 (tiles, triangles, construction and \
         crack-elimination time, simplification, FPS)",
        "The figures exist only as the text output of the example `entropy_table` \
         (terrain-app/examples); no `terrain` command reports the quadtree's construction and \
         crack-elimination times, and our E0 is in percent of the largest entropy (the \
         paper's 10-18 barely simplify at our entropy scale, see \
         `terrain_visibility::entropy::source::EntropyScale`), so the rows need a mapping \
         first.",
    );
    let mut p = Table::new(
        "n = 2,509,683 scattered points, D = 8.",
        &[
            "E0",
            "Tiles",
            "Triangles",
            "Quadtree construction (s)",
            "Crack elimination (ms)",
            "Simplification (%)",
            "FPS",
        ],
    );
    for r in [
        [0.0, 65_536.0, 131_072.0, 19.7, 86.0, 0.0, 224.0],
        [10.0, 58_672.0, 122_895.0, 17.1, 77.0, 6.24, 241.0],
        [12.0, 46_375.0, 104_309.0, 13.3, 64.0, 20.42, 268.0],
        [14.0, 29_174.0, 71_645.0, 8.6, 48.0, 45.34, 295.0],
        [16.0, 11_683.0, 33_009.0, 2.9, 29.0, 74.81, 319.0],
        [18.0, 4_596.0, 14_696.0, 0.8, 21.0, 88.79, 332.0],
    ] {
        p.rows.push(vec![
            num(r[0], 0),
            num(r[1], 0),
            num(r[2], 0),
            num(r[3], 1),
            num(r[4], 0),
            num(r[5], 2),
            num(r[6], 0),
        ]);
    }
    t1.paper = Some(p);
    let mut t2 = Section::missing(
        "Table 2",
        "Data description and algorithm performance on Puget Sound and Grand Canyon",
        "Same gap as Table 1 (construction and crack times are not reported by a `terrain` \
         command); the paper's Puget Sound is 111.6 MB at D = 10, beyond the shared 1k map's \
         depth, and its per-frame cost on our side is 0.1-1 s on a 1025^2 grid (issue 17).",
    );
    let mut p2 = Table::new(
        "",
        &[
            "Location",
            "Size (M)",
            "D",
            "E0",
            "Tiles",
            "Triangles",
            "Quadtree (s)",
            "Cracks (ms)",
            "Simplification (%)",
        ],
    );
    p2.rows.push(vec![
        text("Puget Sound"),
        num(111.6, 1),
        num(10.0, 0),
        num(5.0, 0),
        num(887_095.0, 0),
        num(1_843_397.0, 0),
        num(295.5, 1),
        num(1128.0, 0),
        num(12.10, 2),
    ]);
    p2.rows.push(vec![
        text("Grand Canyon"),
        num(228.0, 1),
        num(11.0, 0),
        num(2.0, 0),
        num(3_699_376.0, 0),
        num(7_674_913.0, 0),
        num(989.6, 1),
        num(4752.0, 0),
        num(8.51, 2),
    ]);
    t2.paper = Some(p2);
    PaperDoc {
        key: "entropy".into(),
        title: "Chen et al. 2018, \"Local curvature entropy-based 3D terrain representation \
                using a comprehensive Quadtree\" (the entropy paper)"
            .into(),
        differences: vec!["No table produced yet (see below).".into()],
        commands: Vec::new(),
        load: Vec::new(),
        quick: false,
        sections: vec![t1, t2],
    }
}
