//! Bounded resources (docs/reliability.md): a mesh file's declared counts are checked against
//! the data present before anything is allocated; a count no file could hold is a clean error
//! naming the file, never an allocation failure or a panic.

use softcap_mesh::{read_ply_from, read_tetgen_from};

#[test]
fn tetgen_counts_beyond_the_data_are_refused() {
    let node = b"1000000000000000 3 0 0\n1 0 0 0\n";
    let ele = b"1 4 0\n1 1 1 1 1\n";
    let e = read_tetgen_from(&node[..], "m.node", &ele[..], "m.ele").unwrap_err();
    assert!(e.to_string().contains("m.node"), "{e}");
    let node = b"4 3 0 0\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n";
    let ele = b"18446744073709551615 4 0\n1 1 2 3 4\n";
    let e = read_tetgen_from(&node[..], "m.node", &ele[..], "m.ele").unwrap_err();
    assert!(e.to_string().contains("m.ele"), "{e}");
}

#[test]
fn ply_counts_beyond_the_data_are_refused() {
    for header in [
        "element vertex 18446744073709551615\nproperty float x\nproperty float y\nproperty float z\n",
        "element vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 4000000000\nproperty list uint int vertex_indices\n",
    ] {
        for format in ["ascii", "binary_little_endian"] {
            let text =
                format!("ply\nformat {format} 1.0\n{header}end_header\n0 0 0\n1 0 0\n0 1 0\n");
            let e = read_ply_from(text.as_bytes(), "m.ply").unwrap_err();
            assert!(e.to_string().contains("m.ply"), "{e}");
        }
    }
    // A face list whose declared length (4 billion indices) exceeds the data.
    let mut bin = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uint int vertex_indices\nend_header\n".to_vec();
    for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        bin.extend_from_slice(&v.to_le_bytes());
    }
    bin.extend_from_slice(&4_000_000_000u32.to_le_bytes());
    let e = read_ply_from(&bin[..], "m.ply").unwrap_err();
    assert!(e.to_string().contains("m.ply"), "{e}");
}

#[test]
fn msh_counts_beyond_the_data_are_refused() {
    let text = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 1000000000000 1 1000000000000\n3 1 0 1000000000000\n1\n0 0 0\n$EndNodes\n";
    let e = softcap_mesh::io::msh::parse_msh_bytes(text.as_bytes(), "m.msh").unwrap_err();
    assert!(e.to_string().contains("m.msh"), "{e}");
}
