//! Unit tests of the export writers and readers: round trips, headers, bad input.

use super::*;
use crate::pipeline::FusedLidar;
use rand::{Rng, SeedableRng};

fn lidar(channel: LidarChannel, range: std::ops::Range<usize>) -> FusedLidar {
    FusedLidar::identity(channel, range)
}

/// A random cloud of `n` points over the given LiDARs (split evenly), with its covariances.
fn random_cloud(n: usize, channels: &[LidarChannel], seed: u64) -> (FusedCloud, Vec<[f32; 6]>) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut c = FusedCloud::default();
    let per = n.div_ceil(channels.len().max(1));
    for (k, ch) in channels.iter().enumerate() {
        let range = (k * per).min(n)..((k + 1) * per).min(n);
        c.source.extend(std::iter::repeat_n(k as u8, range.len()));
        c.lidars.push(lidar(*ch, range));
    }
    let mut v = |scale: f32| rng.random_range(-scale..scale);
    for _ in 0..n {
        c.x.push(v(80.0));
        c.y.push(v(80.0));
        c.z.push(v(5.0));
        c.intensity.push(v(100.0).abs());
        c.trace.push(v(1.0).abs());
    }
    let cov = (0..n)
        .map(|_| std::array::from_fn(|_| v(0.5)))
        .collect::<Vec<[f32; 6]>>();
    (c, cov)
}

fn opts(format: Format, covariance: Option<&[[f32; 6]]>) -> ExportOptions<'_> {
    ExportOptions {
        format,
        covariance,
        comment: "",
    }
}

fn read_as(format: Format, bytes: &[u8]) -> Result<ExportedCloud, ExportError> {
    match format {
        Format::Ply => read_ply(bytes),
        Format::Pcd => read_pcd(bytes),
    }
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn assert_same(c: &FusedCloud, cov: Option<&[[f32; 6]]>, r: &ExportedCloud) {
    assert_eq!(r.len(), c.len());
    assert_eq!(bits(&r.x), bits(&c.x));
    assert_eq!(bits(&r.y), bits(&c.y));
    assert_eq!(bits(&r.z), bits(&c.z));
    assert_eq!(bits(&r.intensity), bits(&c.intensity));
    assert_eq!(bits(&r.trace), bits(&c.trace));
    let ids: Vec<u8> = c
        .source
        .iter()
        .map(|&s| lidar_id(c.lidars[s as usize].channel))
        .collect();
    assert_eq!(r.lidar, ids);
    match (cov, &r.covariance) {
        (None, None) => {}
        (Some(a), Some(b)) => {
            let flat = |m: &[[f32; 6]]| m.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(flat(a), flat(b));
        }
        (a, b) => panic!("covariance written {} read {}", a.is_some(), b.is_some()),
    }
}

#[test]
fn round_trips_bit_for_bit() {
    let (c, cov) = random_cloud(1000, &LidarChannel::ALL, 7);
    for format in Format::ALL {
        for with_cov in [false, true] {
            let opts = ExportOptions {
                format,
                covariance: with_cov.then_some(cov.as_slice()),
                comment: "dataset d sample s\nalpha 0.04",
            };
            let bytes = encode(&c, &opts).unwrap();
            let r = read(&bytes).unwrap();
            assert_same(&c, opts.covariance, &r);
            assert!(
                r.comments.iter().any(|l| l == "dataset d sample s alpha 0.04"),
                "{format}: {:?}",
                r.comments
            );
            assert_eq!(read_as(format, &bytes).unwrap().len(), 1000);
        }
    }
}

#[test]
fn lidar_field_is_the_channel_not_the_frame_position() {
    // A sample without LIDAR_FRONT_LEFT: source 1 is LIDAR_FRONT_RIGHT and must write 2.
    let (c, _) = random_cloud(10, &[LidarChannel::Top, LidarChannel::FrontRight], 1);
    let r = read(&encode(&c, &opts(Format::Ply, None)).unwrap()).unwrap();
    assert_eq!(r.lidar, [0, 0, 0, 0, 0, 2, 2, 2, 2, 2]);
    assert_eq!(lidar_channel(2), Some(LidarChannel::FrontRight));
    assert_eq!(lidar_channel(3), None);
}

#[test]
fn headers_are_what_the_tools_expect() {
    let (c, cov) = random_cloud(3, &LidarChannel::ALL, 2);
    let header = |format, cov: Option<&[[f32; 6]]>| {
        let bytes = encode(
            &c,
            &ExportOptions {
                format,
                covariance: cov,
                comment: "src",
            },
        )
        .unwrap();
        let end = match format {
            Format::Ply => b"end_header\n".as_slice(),
            Format::Pcd => b"DATA binary\n".as_slice(),
        };
        let at = bytes.windows(end.len()).position(|w| w == end).unwrap() + end.len();
        assert_eq!(
            bytes.len() - at,
            3 * record_size(cov.is_some()),
            "{format}: packed records"
        );
        String::from_utf8(bytes[..at].to_vec()).unwrap()
    };
    let ply = header(Format::Ply, Some(&cov));
    let lines: Vec<&str> = ply.lines().collect();
    assert_eq!(
        lines[..3],
        ["ply", "format binary_little_endian 1.0", "comment src"]
    );
    for l in [
        "element vertex 3",
        "property float x",
        "property float intensity",
        "property uchar lidar",
        "property float trace",
        "property float xi_xx",
        "property float xi_zz",
    ] {
        assert!(lines.contains(&l), "{l} in\n{ply}");
    }
    let props: Vec<&str> = lines.iter().filter_map(|l| l.strip_prefix("property ")).collect();
    assert_eq!(props.len(), 12);
    assert_eq!(
        props[6..],
        [
            "float xi_xx",
            "float xi_xy",
            "float xi_xz",
            "float xi_yy",
            "float xi_yz",
            "float xi_zz"
        ]
    );
    let pcd = header(Format::Pcd, None);
    let lines: Vec<&str> = pcd.lines().collect();
    assert!(lines.contains(&"# src"), "{pcd}");
    let tail = &lines[lines.len() - 10..];
    assert_eq!(
        tail,
        [
            "VERSION 0.7",
            "FIELDS x y z intensity lidar trace",
            "SIZE 4 4 4 4 1 4",
            "TYPE F F F F U F",
            "COUNT 1 1 1 1 1 1",
            "WIDTH 3",
            "HEIGHT 1",
            "VIEWPOINT 0 0 0 1 0 0 0",
            "POINTS 3",
            "DATA binary",
        ]
    );
    let pcd = header(Format::Pcd, Some(&cov));
    assert!(pcd.contains("\nFIELDS x y z intensity lidar trace xi_xx xi_xy xi_xz xi_yy xi_yz xi_zz\n"));
    assert!(pcd.contains("\nSIZE 4 4 4 4 1 4 4 4 4 4 4 4\nTYPE F F F F U F F F F F F F\n"));
}

#[test]
fn zero_points_is_a_valid_empty_file() {
    let c = FusedCloud::default();
    for format in Format::ALL {
        for cov in [None, Some([].as_slice())] {
            let bytes = encode(&c, &opts(format, cov)).unwrap();
            let r = read(&bytes).unwrap();
            assert!(r.is_empty());
            assert_eq!(r.covariance.is_some(), cov.is_some());
        }
    }
}

#[test]
fn format_from_name_and_extension() {
    assert_eq!("ply".parse::<Format>(), Ok(Format::Ply));
    assert_eq!("PCD".parse::<Format>(), Ok(Format::Pcd));
    assert!("las".parse::<Format>().unwrap_err().contains("las"));
    assert_eq!(Format::from_path(Path::new("a/b.PLY")), Some(Format::Ply));
    assert_eq!(Format::from_path(Path::new("cloud.pcd")), Some(Format::Pcd));
    assert_eq!(Format::from_path(Path::new("cloud")), None);
    assert_eq!(Format::from_path(Path::new("cloud.xyz")), None);
}

#[test]
fn export_rejects_an_inconsistent_cloud() {
    let (mut c, cov) = random_cloud(4, &LidarChannel::ALL, 3);
    let e = encode(&c, &opts(Format::Pcd, Some(&cov[..3]))).unwrap_err();
    assert!(
        matches!(e, ExportError::CovarianceLength { points: 4, got: 3 }),
        "{e}"
    );
    c.source[2] = 3;
    let e = encode(&c, &opts(Format::Pcd, None)).unwrap_err();
    assert!(e.to_string().contains("point 2"), "{e}");
    c.trace.pop();
    let e = encode(&c, &opts(Format::Pcd, None)).unwrap_err();
    assert!(e.to_string().contains("trace"), "{e}");
}

#[test]
fn writes_atomically_and_names_the_file() {
    let (c, cov) = random_cloud(50, &LidarChannel::ALL, 4);
    let dir = std::env::temp_dir().join(format!("mlod-export-{}", std::process::id()));
    let path = dir.join("cloud.ply");
    let opts = ExportOptions {
        format: Format::Ply,
        covariance: Some(&cov),
        comment: "x",
    };
    write(&path, &c, &opts).unwrap();
    assert_same(&c, Some(&cov), &read_file(&path).unwrap());
    let e = read_file(&dir.join("missing.pcd")).unwrap_err();
    assert!(e.to_string().contains("missing.pcd"), "{e}");
    let e = write(&dir.join("cloud.ply/inside.ply"), &c, &opts).unwrap_err();
    assert!(e.to_string().contains("cloud.ply"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Replaces the first `from` in the header part of `bytes` with `to`.
fn edit(bytes: &[u8], from: &str, to: impl AsRef<[u8]>) -> Vec<u8> {
    let at = bytes
        .windows(from.len())
        .position(|w| w == from.as_bytes())
        .unwrap();
    [&bytes[..at], to.as_ref(), &bytes[at + from.len()..]].concat()
}

#[test]
fn readers_reject_bad_input_with_a_reason() {
    let (c, cov) = random_cloud(20, &LidarChannel::ALL, 5);
    let enc = |format| {
        let o = ExportOptions {
            comment: "s",
            ..opts(format, Some(&cov))
        };
        encode(&c, &o).unwrap()
    };
    let (ply, pcd) = (enc(Format::Ply), enc(Format::Pcd));
    use Format::{Pcd, Ply};
    let no_end = b"ply\nformat binary_little_endian 1.0\nelement vertex 1\n".to_vec();
    let huge = "4611686018427387904";
    let cases: Vec<(&str, Format, Vec<u8>, &str)> = vec![
        ("truncated data", Ply, ply[..ply.len() - 1].to_vec(), "needs"),
        (
            "header only",
            Ply,
            ply[..ply.len() - 20 * 45].to_vec(),
            "0 remain",
        ),
        ("no end", Ply, no_end, "end_header"),
        ("empty", Ply, Vec::new(), "end_header"),
        (
            "count too big",
            Ply,
            edit(&ply, "vertex 20", "vertex 21"),
            "needs",
        ),
        (
            "count too small",
            Ply,
            edit(&ply, "vertex 20", "vertex 19"),
            "45 bytes after",
        ),
        (
            "absurd count",
            Ply,
            edit(&ply, "vertex 20", "vertex 18446744073709551615"),
            "usize::MAX",
        ),
        ("bad count", Ply, edit(&ply, "vertex 20", "vertex -3"), "line 5"),
        ("ascii", Ply, edit(&ply, "binary_little_endian", "ascii"), "ascii"),
        (
            "big endian",
            Ply,
            edit(&ply, "binary_little_endian", "binary_big_endian"),
            "big_endian",
        ),
        (
            "wrong type",
            Ply,
            edit(&ply, "float trace", "double trace"),
            "'trace' is double",
        ),
        (
            "missing field",
            Ply,
            edit(&ply, "float intensity", "float brightness"),
            "'intensity'",
        ),
        (
            "half covariance",
            Ply,
            edit(&ply, "float xi_yz", "float xi_zy"),
            "xi_yz",
        ),
        ("unknown type", Ply, edit(&ply, "float y", "flt y"), "'flt'"),
        ("no magic", Ply, edit(&ply, "ply\n", "plx\n"), "line 1"),
        (
            "list",
            Ply,
            edit(&ply, "uchar lidar", "list uchar int lidar"),
            "list",
        ),
        (
            "non-UTF-8",
            Ply,
            edit(&ply, "comment s", b"comment \xff"),
            "line 3 is not UTF-8",
        ),
        (
            "no vertex",
            Ply,
            edit(&ply, "element vertex", "element points"),
            "element vertex",
        ),
        ("truncated", Pcd, pcd[..pcd.len() - 3].to_vec(), "needs"),
        (
            "no DATA",
            Pcd,
            b"VERSION 0.7\nFIELDS x\nSIZE 4\nTYPE F\n".to_vec(),
            "DATA",
        ),
        (
            "count too big",
            Pcd,
            edit(&edit(&pcd, "WIDTH 20", "WIDTH 99"), "POINTS 20", "POINTS 99"),
            "needs",
        ),
        (
            "count too small",
            Pcd,
            edit(&edit(&pcd, "WIDTH 20", "WIDTH 19"), "POINTS 20", "POINTS 19"),
            "bytes after",
        ),
        (
            "points vs width",
            Pcd,
            edit(&pcd, "POINTS 20", "POINTS 21"),
            "WIDTH",
        ),
        (
            "absurd",
            Pcd,
            edit(
                &edit(&pcd, "WIDTH 20", format!("WIDTH {huge}")),
                "POINTS 20",
                format!("POINTS {huge}"),
            ),
            "usize::MAX",
        ),
        (
            "absurd size",
            Pcd,
            edit(&pcd, "COUNT 1 1", format!("COUNT 1 {huge}")),
            "absurdly large",
        ),
        (
            "absurd stride",
            Pcd,
            edit(
                &pcd,
                "COUNT 1 1 1",
                "COUNT 1 2305843009213693952 2305843009213693952",
            ),
            "usize::MAX",
        ),
        (
            "sizes",
            Pcd,
            edit(&pcd, "SIZE 4 4 4 4 1 4", "SIZE 4 4 4 4 1"),
            "11 SIZE values for 12",
        ),
        ("bad size", Pcd, edit(&pcd, "SIZE 4", "SIZE four"), "'four'"),
        ("bad type", Pcd, edit(&pcd, "TYPE F F", "TYPE Q F"), "'Q'"),
        (
            "lidar type",
            Pcd,
            edit(&pcd, "SIZE 4 4 4 4 1 4", "SIZE 4 4 4 4 2 4"),
            "'lidar'",
        ),
        ("ascii", Pcd, edit(&pcd, "DATA binary", "DATA ascii"), "ascii"),
        (
            "compressed",
            Pcd,
            edit(&pcd, "DATA binary", "DATA binary_compressed"),
            "compressed",
        ),
        ("version", Pcd, edit(&pcd, "VERSION 0.7", "VERSION 0.5"), "0.5"),
        (
            "unknown key",
            Pcd,
            edit(&pcd, "VIEWPOINT", "VIEWPORT"),
            "VIEWPORT",
        ),
        ("no fields", Pcd, edit(&pcd, "FIELDS", "# FIELDS"), "FIELDS"),
        ("not a number", Pcd, edit(&pcd, "HEIGHT 1", "HEIGHT one"), "'one'"),
    ];
    for (name, format, bytes, needle) in cases {
        let e = read_as(format, &bytes).expect_err(name).to_string();
        assert!(e.contains(needle), "{format} {name}: '{e}' lacks '{needle}'");
        assert!(read(&bytes).is_err(), "{format} {name}");
    }
    // Every prefix of a valid file fails cleanly (or reads, for the full length).
    for bytes in [&ply, &pcd] {
        for cut in (0..bytes.len()).step_by(7) {
            assert!(read(&bytes[..cut]).is_err(), "prefix {cut} read");
        }
    }
    // Flipping any header byte never panics.
    for bytes in [&ply, &pcd] {
        for i in 0..600.min(bytes.len()) {
            let mut b = bytes.clone();
            b[i] ^= 0x5a;
            let _ = read(&b);
        }
    }
}

#[test]
fn readers_skip_unknown_fields_in_any_order() {
    // A PCD with the fields shuffled, a 2-float extra, and no covariance.
    let mut bytes = b"# hand-written\nVERSION .7\nFIELDS trace extra lidar z y x intensity\n\
SIZE 4 4 1 4 4 4 4\nTYPE F F U F F F F\nCOUNT 1 2 1 1 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA binary\n"
        .to_vec();
    for i in 0..2u8 {
        let f = f32::from(i);
        for v in [0.5 + f, 9.0, 9.0] {
            bytes.extend_from_slice(&f32::to_le_bytes(v));
        }
        bytes.push(i + 1);
        for v in [3.0 + f, 2.0 + f, 1.0 + f, 10.0 * f] {
            bytes.extend_from_slice(&f32::to_le_bytes(v));
        }
    }
    let r = read_pcd(&bytes).unwrap();
    assert_eq!(r.x, [1.0, 2.0]);
    assert_eq!(r.y, [2.0, 3.0]);
    assert_eq!(r.z, [3.0, 4.0]);
    assert_eq!(r.intensity, [0.0, 10.0]);
    assert_eq!(r.trace, [0.5, 1.5]);
    assert_eq!(r.lidar, [1, 2]);
    assert_eq!(r.covariance, None);
    assert_eq!(r.comments, ["hand-written"]);
    // A PLY with a face-less extra element before the vertices and a double property.
    let mut ply = b"ply\r\nformat binary_little_endian 1.0\r\nelement camera 1\r\nproperty short k\r\n\
element vertex 1\r\nproperty double t\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\n\
property float intensity\r\nproperty uint8 lidar\r\nproperty float32 trace\r\nend_header\r\n\x01\x02"
        .to_vec();
    ply.extend_from_slice(&7.0f64.to_le_bytes());
    for v in [1.0f32, 2.0, 3.0, 4.0] {
        ply.extend_from_slice(&v.to_le_bytes());
    }
    ply.push(0);
    ply.extend_from_slice(&0.25f32.to_le_bytes());
    let r = read_ply(&ply).unwrap();
    assert_eq!(
        (r.x[0], r.y[0], r.z[0], r.intensity[0], r.lidar[0], r.trace[0]),
        (1.0, 2.0, 3.0, 4.0, 0, 0.25)
    );
}

#[test]
fn xi_is_stored_as_the_upper_triangle_row_by_row() {
    // In memory (covariance6 order): xx, yy, zz, xy, xz, yz = 0..6.
    let (c, _) = random_cloud(1, &[LidarChannel::Top], 6);
    let cov = [[0.0, 1.0, 2.0, 3.0, 4.0, 5.0]];
    let bytes = encode(&c, &opts(Format::Pcd, Some(&cov))).unwrap();
    let tail: Vec<f32> = bytes[bytes.len() - 24..]
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect();
    // xi_xx, xi_xy, xi_xz, xi_yy, xi_yz, xi_zz.
    assert_eq!(tail, [0.0, 3.0, 4.0, 1.0, 5.0, 2.0]);
    assert_eq!(read(&bytes).unwrap().covariance.unwrap(), cov);
}
