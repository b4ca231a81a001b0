//! The scattered-points reader: formats it accepts, and errors that name the file and line.

mod common;

use common::TempFile;
use terrain_core::points::{PointsErrorKind, parse_points, read_points};

/// `text` written to `name` in a temporary folder of its own ([`common::write_temp`]), removed
/// (also on a panic) when the returned guard is dropped.
fn scratch(name: &str, text: &[u8]) -> TempFile {
    common::write_temp("terrain-points-test-", name, text)
}

#[test]
fn reads_whitespace_csv_header_and_comments() {
    let text = "x,y,z\n# a comment\n1,2,3\n\n4 5 6\n7;8;9;extra\n  -1.5e3\t2.25   0.5  \n";
    let pts = parse_points(text).unwrap();
    assert_eq!(pts.len(), 4);
    assert_eq!(pts[0].to_array(), [1.0, 2.0, 3.0]);
    assert_eq!(pts[2].to_array(), [7.0, 8.0, 9.0]);
    assert_eq!(pts[3].to_array(), [-1500.0, 2.25, 0.5]);
}

#[test]
fn errors_name_the_file_and_the_line() {
    let p = scratch("bad.xyz", b"1 2 3\n4 5 6\n7 oops 9\n");
    let e = read_points(&p).unwrap_err();
    let msg = e.to_string();
    assert!(msg.contains("bad.xyz") && msg.contains("line 3"), "{msg}");
    assert!(matches!(e.kind, PointsErrorKind::BadLine { line: 3, .. }));
    let p = scratch("short.xyz", b"1 2 3\n4 5\n");
    let e = read_points(&p).unwrap_err();
    assert!(
        matches!(e.kind, PointsErrorKind::BadLine { line: 2, message, .. } if message.contains("fewer"))
    );
    let p = scratch("inf.xyz", b"1 2 3\n4 5 inf\n1 1 1\n");
    assert!(matches!(read_points(&p).unwrap_err().kind, PointsErrorKind::BadLine { line: 2, .. }));
    let p = scratch("two.xyz", b"1 2 3\n4 5 6\n");
    assert!(matches!(read_points(&p).unwrap_err().kind, PointsErrorKind::TooFew(2)));
    let p = scratch("bin.xyz", &[0xff, 0xfe, 0x00, 0x31]);
    assert!(matches!(read_points(&p).unwrap_err().kind, PointsErrorKind::NotText(0)));
    let missing = std::env::temp_dir().join("terrain-points-test-missing/none.xyz");
    let e = read_points(&missing).unwrap_err();
    assert!(matches!(e.kind, PointsErrorKind::Io(_)) && e.to_string().contains("none.xyz"));
    // A non-numeric line after data is an error, not a header.
    assert!(matches!(
        parse_points("1 2 3\nx y z\n4 5 6\n").unwrap_err(),
        PointsErrorKind::BadLine { line: 2, .. }
    ));
}
