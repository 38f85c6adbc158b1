//! Compiles `proto/softcap/*.proto` with `protox` (a pure-Rust protobuf compiler, so no `protoc`
//! is needed) into a `FileDescriptorSet`, then generates the prost message structs from that set
//! with `prost-build`. The `.proto` files are the single source of truth: the Rust types and the
//! schemas embedded in every MCAP file come from the same descriptor set and cannot drift apart.

use std::path::PathBuf;

use prost::Message as _;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let proto_dir = PathBuf::from("proto");
    let mut files: Vec<PathBuf> = std::fs::read_dir(proto_dir.join("softcap"))?
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "proto"))
        .collect();
    // Sorted so the descriptor set (and therefore every file's digest) is deterministic.
    files.sort();
    let relative: Vec<PathBuf> = files
        .iter()
        .map(|p| p.strip_prefix(&proto_dir).map(PathBuf::from))
        .collect::<Result<_, _>>()?;
    // the folder itself too: its mtime changes when a .proto file is added or removed
    println!("cargo:rerun-if-changed=proto");
    println!("cargo:rerun-if-changed=proto/softcap");
    for f in &files {
        println!("cargo:rerun-if-changed={}", f.display());
    }

    let mut compiler = protox::Compiler::new([&proto_dir])?;
    compiler.include_imports(true).include_source_info(true);
    compiler.open_files(&relative)?;
    let with_docs = compiler.file_descriptor_set();

    // The embedded schema drops source info (comments, spans): smaller files, same decoding.
    let mut embedded = with_docs.clone();
    for file in &mut embedded.file {
        file.source_code_info = None;
    }
    let out_dir = PathBuf::from(std::env::var("OUT_DIR")?);
    // Unlink the previous outputs instead of overwriting them in place: a target directory seeded
    // by hard links (several worktrees sharing one prebuilt tree) would otherwise see this
    // worktree's generated code appear in every other one.
    for f in ["softcap_descriptor_set.bin", "softcap.rs"] {
        let _ = std::fs::remove_file(out_dir.join(f));
    }
    std::fs::write(
        out_dir.join("softcap_descriptor_set.bin"),
        embedded.encode_to_vec(),
    )?;

    prost_build::Config::new()
        .enable_type_names()
        .compile_fds(with_docs)?;
    Ok(())
}
