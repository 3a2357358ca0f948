//! `EXT_meshopt_compression`: a buffer view that carries the extension is decoded from the
//! compressed bytes its extension object names (modes ATTRIBUTES, TRIANGLES, INDICES; filters
//! NONE, OCTAHEDRAL, QUATERNION, EXPONENTIAL), with meshoptimizer's reference decoders (the
//! `meshopt` crate). Every rule of the extension that the decoders rely on is checked here first,
//! so that a malformed file gets an error, never an assertion in the C++ code; the decoders
//! themselves are written for untrusted input (they never read or write out of bounds and run in
//! time linear in their input and output).

use serde_json::Value;

/// The extension's name.
pub(crate) const EXTENSION: &str = "EXT_meshopt_compression";

/// How the compressed bytes encode the view (the extension's `mode`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Mode {
    /// Vertex attributes (any elements), deltas per byte.
    Attributes,
    /// A triangle list's indices.
    Triangles,
    /// Any other indices.
    Indices,
}

impl Mode {
    fn name(self) -> &'static str {
        match self {
            Mode::Attributes => "ATTRIBUTES",
            Mode::Triangles => "TRIANGLES",
            Mode::Indices => "INDICES",
        }
    }
}

/// What is applied to the decoded attributes (the extension's `filter`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Filter {
    /// The decoded bytes as they are.
    None,
    /// Unit vectors in octahedral encoding, into 8- or 16-bit normalised XYZ (W kept).
    Octahedral,
    /// Unit quaternions, three components and the largest one's index, into 16-bit XYZW.
    Quaternion,
    /// Floats as an 8-bit exponent and a 24-bit mantissa, into f32.
    Exponential,
}

impl Filter {
    fn name(self) -> &'static str {
        match self {
            Filter::None => "NONE",
            Filter::Octahedral => "OCTAHEDRAL",
            Filter::Quaternion => "QUATERNION",
            Filter::Exponential => "EXPONENTIAL",
        }
    }
}

/// A compressed buffer view as its extension object gives it, checked against the rules of the
/// extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Compressed {
    /// The buffer holding the compressed bytes.
    pub(crate) buffer: usize,
    /// Where they start in it.
    pub(crate) offset: u64,
    /// How many there are.
    pub(crate) length: u64,
    /// Bytes per decoded element.
    pub(crate) stride: usize,
    /// Decoded elements.
    pub(crate) count: usize,
    pub(crate) mode: Mode,
    pub(crate) filter: Filter,
}

impl Compressed {
    /// The size of the decoded view in bytes.
    pub(crate) fn decoded_len(&self) -> u64 {
        self.count as u64 * self.stride as u64
    }
}

/// Reads and checks the extension object `ext` of a buffer view whose own `byteLength` and
/// `byteStride` are `view_length` and `view_stride`. The error says what is wrong (the caller
/// names the view and the extension).
pub(crate) fn parse(
    ext: &Value,
    view_length: u64,
    view_stride: Option<usize>,
) -> Result<Compressed, String> {
    let integer = |key: &str, required: bool| -> Result<Option<u64>, String> {
        match ext.get(key) {
            None if required => Err(format!("{key} is missing")),
            None => Ok(None),
            Some(v) => v
                .as_u64()
                .map(Some)
                .ok_or_else(|| format!("{key} must be an integer of at least 0, not {v}")),
        }
    };
    if !ext.is_object() {
        return Err("the extension must be an object".into());
    }
    let buffer = integer("buffer", true)?.unwrap_or_default();
    let offset = integer("byteOffset", false)?.unwrap_or(0);
    let length = integer("byteLength", true)?.unwrap_or_default();
    let stride = integer("byteStride", true)?.unwrap_or_default();
    let count = integer("count", true)?.unwrap_or_default();
    let mode = match ext.get("mode").and_then(Value::as_str) {
        Some("ATTRIBUTES") => Mode::Attributes,
        Some("TRIANGLES") => Mode::Triangles,
        Some("INDICES") => Mode::Indices,
        Some(other) => {
            return Err(format!("unknown mode \"{other}\" (ATTRIBUTES, TRIANGLES or INDICES)"))
        }
        None => return Err("mode must be ATTRIBUTES, TRIANGLES or INDICES".into()),
    };
    let filter = match ext.get("filter").map(|f| f.as_str()) {
        None | Some(Some("NONE")) => Filter::None,
        Some(Some("OCTAHEDRAL")) => Filter::Octahedral,
        Some(Some("QUATERNION")) => Filter::Quaternion,
        Some(Some("EXPONENTIAL")) => Filter::Exponential,
        Some(Some(other)) => {
            return Err(format!(
                "unknown filter \"{other}\" (NONE, OCTAHEDRAL, QUATERNION or EXPONENTIAL)"
            ))
        }
        Some(None) => {
            return Err("filter must be NONE, OCTAHEDRAL, QUATERNION or EXPONENTIAL".into())
        }
    };
    let stride_ok = match (mode, filter) {
        (Mode::Attributes, Filter::None) => stride % 4 == 0 && (4..=256).contains(&stride),
        (Mode::Attributes, Filter::Octahedral) => stride == 4 || stride == 8,
        (Mode::Attributes, Filter::Quaternion) => stride == 8,
        (Mode::Attributes, Filter::Exponential) => stride % 4 == 0 && (4..=256).contains(&stride),
        (Mode::Triangles | Mode::Indices, Filter::None) => stride == 2 || stride == 4,
        (Mode::Triangles | Mode::Indices, _) => {
            return Err(format!("mode {} takes no filter, not {}", mode.name(), filter.name()))
        }
    };
    if !stride_ok {
        return Err(format!(
            "byteStride {stride} is not allowed for mode {} with filter {} ({})",
            mode.name(),
            filter.name(),
            match (mode, filter) {
                (Mode::Attributes, Filter::None | Filter::Exponential) =>
                    "a multiple of 4 up to 256",
                (Mode::Attributes, Filter::Octahedral) => "4 or 8",
                (Mode::Attributes, Filter::Quaternion) => "8",
                _ => "2 or 4",
            }
        ));
    }
    if mode == Mode::Triangles && count % 3 != 0 {
        return Err(format!("count {count} of a TRIANGLES view is not a multiple of 3"));
    }
    if let Some(parent) = view_stride {
        if parent as u64 != stride {
            return Err(format!(
                "byteStride {stride} differs from the buffer view's byteStride {parent}"
            ));
        }
    }
    if count.checked_mul(stride) != Some(view_length) {
        return Err(format!(
            "count {count} x byteStride {stride} is not the buffer view's byteLength {view_length}"
        ));
    }
    let buffer = usize::try_from(buffer).map_err(|_| format!("buffer {buffer} does not exist"))?;
    let count = usize::try_from(count).map_err(|_| format!("count {count} is too large"))?;
    Ok(Compressed { buffer, offset, length, stride: stride as usize, count, mode, filter })
}

/// Decodes the compressed bytes `src` of `c` into the view's `count x byteStride` bytes. The
/// error says what is wrong with the stream.
pub(crate) fn decode(c: &Compressed, src: &[u8]) -> Result<Vec<u8>, String> {
    let native = |e: ::meshopt::Error| {
        let what = c.mode.name();
        let why = match e {
            ::meshopt::Error::Native(-1) => "unknown header or format version".to_string(),
            ::meshopt::Error::Native(-2) => "truncated or corrupt".to_string(),
            ::meshopt::Error::Native(-3) => {
                "bytes left over after the last element (corrupt, or a wrong count)".to_string()
            }
            other => other.to_string(),
        };
        format!("cannot decode the {what} stream of {} bytes: {why}", src.len())
    };
    let mut out = match c.mode {
        Mode::Attributes => attributes(src, c.count, c.stride).map_err(native)?,
        Mode::Triangles if c.stride == 2 => {
            let v = ::meshopt::decode_index_buffer::<u16>(src, c.count).map_err(native)?;
            v.iter().flat_map(|i| i.to_le_bytes()).collect()
        }
        Mode::Triangles => {
            let v = ::meshopt::decode_index_buffer::<u32>(src, c.count).map_err(native)?;
            v.iter().flat_map(|i| i.to_le_bytes()).collect()
        }
        Mode::Indices if c.stride == 2 => {
            let v = ::meshopt::decode_index_sequence::<u16>(src, c.count).map_err(native)?;
            v.iter().flat_map(|i| i.to_le_bytes()).collect()
        }
        Mode::Indices => {
            let v = ::meshopt::decode_index_sequence::<u32>(src, c.count).map_err(native)?;
            v.iter().flat_map(|i| i.to_le_bytes()).collect()
        }
    };
    apply_filter(c.filter, c.stride, &mut out);
    Ok(out)
}

/// One element of `N` bytes, for the vertex decoder (which takes the element size from the
/// type).
#[derive(Clone, Copy)]
struct Element<const N: usize>([u8; N]);

impl<const N: usize> Default for Element<N> {
    fn default() -> Self {
        Element([0; N])
    }
}

fn attributes_of<const N: usize>(src: &[u8], count: usize) -> ::meshopt::Result<Vec<u8>> {
    let elements = ::meshopt::decode_vertex_buffer::<Element<N>>(src, count)?;
    Ok(elements.iter().flat_map(|e| e.0).collect())
}

/// Decodes an ATTRIBUTES stream of `count` elements of `stride` bytes (a multiple of 4 up to
/// 256, checked by [`parse`]).
fn attributes(src: &[u8], count: usize, stride: usize) -> ::meshopt::Result<Vec<u8>> {
    macro_rules! by_stride {
        ($($n:literal)*) => {
            match stride {
                $($n => attributes_of::<$n>(src, count),)*
                _ => Err(::meshopt::Error::Parse(format!("byteStride {stride} is not allowed"))),
            }
        };
    }
    by_stride!(4 8 12 16 20 24 28 32 36 40 44 48 52 56 60 64 68 72 76 80 84 88 92 96 100 104
        108 112 116 120 124 128 132 136 140 144 148 152 156 160 164 168 172 176 180 184 188 192
        196 200 204 208 212 216 220 224 228 232 236 240 244 248 252 256)
}

/// Applies `filter` in place to decoded elements of `stride` bytes (a stride the filter allows,
/// checked by [`parse`]).
fn apply_filter(filter: Filter, stride: usize, bytes: &mut [u8]) {
    match (filter, stride) {
        (Filter::None, _) => {}
        (Filter::Octahedral, 4) => {
            let mut v: Vec<[u8; 4]> =
                bytes.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect();
            ::meshopt::decode_filter_oct(&mut v);
            bytes.copy_from_slice(v.as_flattened());
        }
        (Filter::Octahedral, _) => {
            let mut v: Vec<[u16; 4]> = bytes.chunks_exact(8).map(u16x4).collect();
            ::meshopt::decode_filter_oct(&mut v);
            write_u16(&v, bytes);
        }
        (Filter::Quaternion, _) => {
            let mut v: Vec<[i16; 4]> =
                bytes.chunks_exact(8).map(|c| u16x4(c).map(|x| x as i16)).collect();
            ::meshopt::decode_filter_quat(&mut v);
            let v: Vec<[u16; 4]> = v.iter().map(|q| q.map(|x| x as u16)).collect();
            write_u16(&v, bytes);
        }
        (Filter::Exponential, _) => {
            let mut v: Vec<[u32; 1]> = bytes
                .chunks_exact(4)
                .map(|c| [u32::from_le_bytes([c[0], c[1], c[2], c[3]])])
                .collect();
            ::meshopt::decode_filter_exp(&mut v);
            for (out, x) in bytes.chunks_exact_mut(4).zip(v) {
                out.copy_from_slice(&x[0].to_le_bytes());
            }
        }
    }
}

fn u16x4(c: &[u8]) -> [u16; 4] {
    [0, 1, 2, 3].map(|i| u16::from_le_bytes([c[2 * i], c[2 * i + 1]]))
}

fn write_u16(v: &[[u16; 4]], bytes: &mut [u8]) {
    for (out, x) in bytes.chunks_exact_mut(2).zip(v.as_flattened()) {
        out.copy_from_slice(&x.to_le_bytes());
    }
}
