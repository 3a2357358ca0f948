//! The binary glTF container (`.glb`): the 12-byte header, the JSON chunk and the optional BIN
//! chunk, with an error for every kind of truncation or inconsistency instead of a panic.

use super::SceneError;

/// The two chunks a GLB file carries.
#[derive(Debug)]
pub(crate) struct Glb<'a> {
    /// The JSON chunk's bytes (may end with padding spaces).
    pub(crate) json: &'a [u8],
    /// The BIN chunk's bytes, if the file has one.
    pub(crate) bin: Option<&'a [u8]>,
}

const MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;

/// Whether the bytes start like a GLB file.
pub(crate) fn is_glb(bytes: &[u8]) -> bool {
    bytes.starts_with(MAGIC)
}

fn err(msg: impl std::fmt::Display) -> SceneError {
    SceneError(format!("GLB: {msg}"))
}

fn u32_at(bytes: &[u8], at: usize) -> Option<u32> {
    let b = bytes.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// Splits a GLB file into its chunks. Unknown chunk types after the JSON chunk are skipped, as the
/// specification asks; bytes after the length the header declares are ignored.
pub(crate) fn parse(bytes: &[u8]) -> Result<Glb<'_>, SceneError> {
    if bytes.len() < 12 {
        return Err(err(format_args!(
            "truncated header: {} bytes, a GLB header needs 12",
            bytes.len()
        )));
    }
    if &bytes[..4] != MAGIC {
        return Err(err(format_args!(
            "bad magic {:?}, expected \"glTF\"",
            String::from_utf8_lossy(&bytes[..4])
        )));
    }
    let version = u32_at(bytes, 4).unwrap_or(0);
    if version != 2 {
        return Err(err(format_args!("container version {version} is not supported (only 2)")));
    }
    let length = u32_at(bytes, 8).unwrap_or(0) as usize;
    if length < 20 {
        return Err(err(format_args!("header length {length} is too small to hold a JSON chunk")));
    }
    if length > bytes.len() {
        return Err(err(format_args!(
            "header says the file has {length} bytes but only {} are present (truncated?)",
            bytes.len()
        )));
    }
    if length < bytes.len() {
        tracing::warn!(
            "GLB: ignoring {} bytes after the declared length {length}",
            bytes.len() - length
        );
    }
    let data = &bytes[..length];

    let mut json: Option<&[u8]> = None;
    let mut bin: Option<&[u8]> = None;
    let mut at = 12usize;
    let mut index = 0usize;
    while at < data.len() {
        if data.len() - at < 8 {
            return Err(err(format_args!("truncated header of chunk {index} at byte {at}")));
        }
        let chunk_len = u32_at(data, at).unwrap_or(0) as usize;
        let chunk_type = u32_at(data, at + 4).unwrap_or(0);
        let start = at + 8;
        let end = start.checked_add(chunk_len).filter(|&e| e <= data.len()).ok_or_else(|| {
            err(format_args!(
                "chunk {index} declares {chunk_len} bytes but only {} remain in the file",
                data.len() - start
            ))
        })?;
        let body = &data[start..end];
        match (index, chunk_type) {
            (0, CHUNK_JSON) => json = Some(body),
            (0, other) => {
                return Err(err(format_args!(
                    "first chunk has type {:?}, expected JSON",
                    String::from_utf8_lossy(&other.to_le_bytes())
                )))
            }
            (_, CHUNK_JSON) => {
                return Err(err(format_args!("chunk {index} is a second JSON chunk")))
            }
            (_, CHUNK_BIN) if bin.is_some() => {
                return Err(err(format_args!("chunk {index} is a second BIN chunk")))
            }
            (1, CHUNK_BIN) => bin = Some(body),
            (_, CHUNK_BIN) => {
                return Err(err(format_args!(
                    "BIN chunk must come right after the JSON chunk, found it as chunk {index}"
                )))
            }
            (_, other) => tracing::debug!("GLB: skipping unknown chunk type {other:#010x}"),
        }
        at = end;
        index += 1;
    }
    let json = json.ok_or_else(|| err("no JSON chunk"))?;
    if json.iter().all(|b| b.is_ascii_whitespace() || *b == 0) {
        return Err(err("the JSON chunk is empty"));
    }
    Ok(Glb { json, bin })
}

/// Builds a GLB file from a JSON text and an optional BIN payload (test helper and tooling).
pub fn build(json: &[u8], bin: Option<&[u8]>) -> Vec<u8> {
    let pad = |n: usize| (4 - n % 4) % 4;
    let json_len = json.len() + pad(json.len());
    let bin_len = bin.map(|b| b.len() + pad(b.len()));
    let total = 12 + 8 + json_len + bin_len.map_or(0, |l| 8 + l);
    assert!(u32::try_from(total).is_ok(), "a GLB holds at most 4 GiB");
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json_len as u32).to_le_bytes());
    out.extend_from_slice(&CHUNK_JSON.to_le_bytes());
    out.extend_from_slice(json);
    out.resize(out.len() + pad(json.len()), b' ');
    if let (Some(bin), Some(len)) = (bin, bin_len) {
        out.extend_from_slice(&(len as u32).to_le_bytes());
        out.extend_from_slice(&CHUNK_BIN.to_le_bytes());
        out.extend_from_slice(bin);
        out.resize(out.len() + pad(bin.len()), 0);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_every_truncation_is_an_error() {
        let file = build(br#"{"asset":{"version":"2.0"}}"#, Some(&[1, 2, 3, 4, 5]));
        let glb = parse(&file).expect("valid");
        assert!(glb.json.starts_with(b"{\"asset\""));
        assert_eq!(&glb.bin.expect("bin")[..5], &[1, 2, 3, 4, 5]);
        for cut in 0..file.len() {
            let e = parse(&file[..cut]).expect_err("truncated file accepted");
            assert!(e.0.starts_with("GLB: "), "{e}");
        }
    }

    #[test]
    fn bad_magic_version_and_chunk_lengths() {
        let mut file = build(br#"{"asset":{"version":"2.0"}}"#, None);
        let mut bad = file.clone();
        bad[0] = b'X';
        assert!(parse(&bad).unwrap_err().0.contains("magic"));
        let mut bad = file.clone();
        bad[4] = 1;
        assert!(parse(&bad).unwrap_err().0.contains("version 1"));
        let mut bad = file.clone();
        bad[12..16].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(parse(&bad).unwrap_err().0.contains("chunk 0"));
        file[16..20].copy_from_slice(b"BIN\0");
        assert!(parse(&file).unwrap_err().0.contains("first chunk"));
    }
}
