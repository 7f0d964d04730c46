#![no_main]
//! Octree cache files. The checks before the nodes are a magic, a version, a key and a
//! blake3 checksum, which random bytes never pass; so the first input byte says which
//! of them the harness makes right (bit 0: magic, version and node size; bit 1: key
//! taken from the file; bit 2: checksum recomputed), and the rest is the file.
use libfuzzer_sys::fuzz_target;

const HEADER: usize = 96;

fuzz_target!(|data: &[u8]| {
    let Some((&flags, file)) = data.split_first() else {
        return;
    };
    let mut file = file.to_vec();
    if file.len() >= HEADER {
        if flags & 1 != 0 {
            file[..8].copy_from_slice(b"PPBOCTR\0");
            file[8..12].copy_from_slice(&ppb::majorant::cache::FORMAT_VERSION.to_le_bytes());
            let node = std::mem::size_of::<ppb::majorant::octree::Node>() as u32;
            file[12..16].copy_from_slice(&node.to_le_bytes());
        }
        if flags & 4 != 0 {
            let sum = *blake3::hash(&file[HEADER..]).as_bytes();
            file[56..88].copy_from_slice(&sum);
        }
    }
    let mut key = [0u8; 32];
    if flags & 2 != 0 && file.len() >= 56 {
        key.copy_from_slice(&file[24..56]);
    }
    let r = ppb::majorant::cache::decode(&file, &key);
    if std::env::var_os("FUZZ_VERBOSE").is_some() {
        eprintln!("cache: {:?}", r.as_ref().map(|t| t.nodes.len()));
    }
});
