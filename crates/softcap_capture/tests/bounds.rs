//! Bounded resources (docs/reliability.md): sizes and counts a file declares are checked against
//! the data present and a documented limit before anything is allocated. Each case is bad input
//! naming the file (exit code 2).

use softcap_capture::depth::{MAX_DEPTH_PIXELS, read_depth_png};
use softcap_capture::{Camera, read_c3d};

fn crc32(bytes: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 == 1 {
                (c >> 1) ^ 0xEDB8_8320
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// A PNG of a 16-bit grayscale header claiming `width × height` and one small zlib stream.
fn png_claiming(width: u32, height: u32) -> Vec<u8> {
    let chunk = |kind: &[u8], data: &[u8]| {
        let mut c = (data.len() as u32).to_be_bytes().to_vec();
        c.extend_from_slice(kind);
        c.extend_from_slice(data);
        let mut crc_input = kind.to_vec();
        crc_input.extend_from_slice(data);
        c.extend_from_slice(&crc32(&crc_input).to_be_bytes());
        c
    };
    let mut ihdr = width.to_be_bytes().to_vec();
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[16, 0, 0, 0, 0]);
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    png.extend(chunk(b"IHDR", &ihdr));
    // zlib of a few zero bytes: far fewer than the header promises.
    png.extend(chunk(
        b"IDAT",
        &[0x78, 0x9c, 0x63, 0x60, 0x00, 0x00, 0x00, 0x02, 0x00, 0x01],
    ));
    png.extend(chunk(b"IEND", &[]));
    png
}

fn camera(width: u32, height: u32) -> Camera {
    let m = softcap_capture::nalgebra::Matrix3::identity();
    let t = softcap_capture::nalgebra::Vector3::zeros();
    Camera::new(
        "d0".into(),
        width,
        height,
        [500.0, 500.0, 8.0, 6.0],
        [0.0; 5],
        m,
        t,
    )
    .unwrap()
}

#[test]
fn a_depth_png_larger_than_the_limit_is_refused_before_decoding() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("000000.png");
    // 60000 × 60000 16-bit pixels would be 7.2 GB; the file is under 100 bytes.
    std::fs::write(&p, png_claiming(60_000, 60_000)).unwrap();
    let e = read_depth_png(&p, &camera(60_000, 60_000)).unwrap_err();
    let m = e.to_string();
    assert!(
        m.contains("000000.png") && m.contains(&MAX_DEPTH_PIXELS.to_string()),
        "{m}"
    );
    assert_eq!(softcap_app::Error::from(e).exit_code(), 2);
    // Within the limit but not the camera's size: refused before decoding too.
    std::fs::write(&p, png_claiming(4000, 3000)).unwrap();
    let m = read_depth_png(&p, &camera(16, 12)).unwrap_err().to_string();
    assert!(m.contains("4000×3000") && m.contains("16×12"), "{m}");
    // The camera's size, but the pixel data is missing: a decode error, not a panic.
    std::fs::write(&p, png_claiming(16, 12)).unwrap();
    let m = read_depth_png(&p, &camera(16, 12)).unwrap_err().to_string();
    assert!(m.contains("cannot decode"), "{m}");
}

/// fixtures/c3d/Optotrak.c3d with its header words (1-based index, u16, little-endian in this
/// file) replaced, read with `read_c3d`.
fn read_optotrak_with_header(
    words: &[(usize, u16)],
) -> softcap_capture::Result<softcap_capture::C3dTake> {
    let dir = tempfile::tempdir().unwrap();
    let src =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/c3d/Optotrak.c3d");
    let mut bytes = std::fs::read(src).unwrap();
    for &(word, value) in words {
        bytes[2 * (word - 1)..2 * word].copy_from_slice(&value.to_le_bytes());
    }
    let p = dir.path().join("take.c3d");
    std::fs::write(&p, &bytes).unwrap();
    read_c3d(&p)
}

/// A C3D header whose frame range promises far more frames than the file holds.
#[test]
fn a_c3d_claiming_more_frames_than_it_holds_is_refused() {
    // words 4 and 5: first and last frame
    match read_optotrak_with_header(&[(4, 1), (5, 65_000)]) {
        Ok(take) => assert!(
            take.positions_m.len() < 65_000,
            "frames beyond the file's data"
        ),
        Err(e) => assert_eq!(softcap_app::Error::from(e).exit_code(), 2),
    }
}

/// A C3D header declaring 65,535 frames of 65,535 markers in a 28 kB file: `c3dio` sizes a grid
/// from the header before it reads anything else (about 100 GB here); `read_c3d` caps the
/// header's frame range at what the file's bytes can hold first (found by the `c3d` fuzz target).
#[test]
fn a_c3d_header_declaring_a_huge_marker_grid_allocates_nothing_for_it() {
    // words 2, 4 and 5: markers, first and last frame
    if let Err(e) = read_optotrak_with_header(&[(2, u16::MAX), (4, 1), (5, u16::MAX)]) {
        assert_eq!(softcap_app::Error::from(e).exit_code(), 2);
    }
}
