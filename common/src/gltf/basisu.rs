//! `KHR_texture_basisu`: KTX2 images holding Basis Universal data, ETC1S (BasisLZ
//! supercompression) or UASTC (none or Zstandard), transcoded to RGBA8 by Basis Universal's
//! reference transcoder (the `basis-universal` crate). The container is read by the `ktx2` crate
//! and checked here first: one 2D image (no array, cubemap or volume), at most 16384 texels a
//! side, its level 0 only (the renderer filters textures itself). The texel count comes from the
//! header, so that [`dimensions`] lets the loader charge the budget before anything is
//! decompressed or transcoded; a Zstandard level is inflated into exactly the size its block
//! count gives, never more.
//!
//! The crate's transcoder reads only `.basis` files (its low-level UASTC entry point sizes an
//! uncompressed output by blocks, not texels, so it is not used), so the image is handed to it
//! as one: the KTX2's level 0 (inflated, for UASTC with Zstandard) and, for ETC1S, its global
//! codebooks, under a `.basis` header ([`basis_file`]); the transcoder's own KTX2 reader feeds
//! the same decoders the same bytes.

use basis_universal::{TranscodeParameters, Transcoder, TranscoderTextureFormat};
use ktx2::{ColorModel, Reader, SupercompressionScheme};

/// The extension's name.
pub(crate) const EXTENSION: &str = "KHR_texture_basisu";

/// The largest width or height the transcoder takes (Basis Universal's own limit).
const MAX_SIDE: u32 = 16384;

/// Whether `bytes` start with the KTX2 identifier.
pub(crate) fn is_ktx2(bytes: &[u8]) -> bool {
    bytes.starts_with(b"\xABKTX 20\xBB\r\n\x1A\n")
}

/// How the image's level 0 is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    /// ETC1S slices with BasisLZ codebooks in the global data.
    Etc1s,
    /// UASTC blocks, Zstandard-compressed or not.
    Uastc { zstd: bool, alpha: bool },
}

/// A checked KTX2 image.
struct Image<'a> {
    reader: Reader<&'a [u8]>,
    width: u32,
    height: u32,
    kind: Kind,
}

/// Reads and checks a KTX2 header. The error says what is wrong (the caller names the image).
fn inspect(bytes: &[u8]) -> Result<Image<'_>, String> {
    let reader = Reader::new(bytes).map_err(|e| format!("KTX2: {e}"))?;
    let h = reader.header();
    if let Some(format) = h.format {
        return Err(format!(
            "KTX2 vkFormat {format:?} is not Basis Universal (KHR_texture_basisu takes vkFormat 0, ETC1S or UASTC)"
        ));
    }
    if h.pixel_height == 0 || h.pixel_depth > 0 || h.layer_count > 1 || h.face_count != 1 {
        return Err(format!(
            "KTX2 of {}x{}x{}, {} layers, {} faces: only one 2D image is supported",
            h.pixel_width, h.pixel_height, h.pixel_depth, h.layer_count, h.face_count
        ));
    }
    if h.pixel_width > MAX_SIDE || h.pixel_height > MAX_SIDE {
        return Err(format!(
            "KTX2 of {}x{} texels: Basis Universal takes at most {MAX_SIDE} a side",
            h.pixel_width, h.pixel_height
        ));
    }
    let model = reader.basic_dfd().and_then(|d| d.color_model);
    let kind = match (model, h.supercompression_scheme) {
        (Some(ColorModel::ETC1S), Some(SupercompressionScheme::BasisLZ)) => Kind::Etc1s,
        (Some(ColorModel::UASTC), None) | (Some(ColorModel::UASTC), Some(SupercompressionScheme::Zstandard)) => {
            // The channel of the first sample: RGB 0, RGBA 3, RRR 4, RRRG 5, RG 6.
            let channel = reader
                .basic_dfd()
                .and_then(|d| d.sample_information.first())
                .map(|s| s.channel_type);
            Kind::Uastc {
                zstd: h.supercompression_scheme.is_some(),
                alpha: matches!(channel, Some(3 | 5)),
            }
        }
        (model, scheme) => {
            return Err(format!(
                "KTX2 with colour model {} and supercompression {}: KHR_texture_basisu takes ETC1S with BasisLZ, or UASTC with none or Zstandard",
                model.map_or("none".to_string(), |m| format!("{m:?}")),
                scheme.map_or("none".to_string(), |s| format!("{s:?}")),
            ))
        }
    };
    Ok(Image { width: h.pixel_width, height: h.pixel_height, kind, reader })
}

/// The width and height a KTX2 image's header gives, once its container is checked.
pub(crate) fn dimensions(bytes: &[u8]) -> Result<(u32, u32), String> {
    inspect(bytes).map(|i| (i.width, i.height))
}

/// Transcodes the level 0 of a KTX2 image into RGBA8 texels, row 0 at the top.
pub(crate) fn decode(bytes: &[u8]) -> Result<Vec<[u8; 4]>, String> {
    let image = inspect(bytes)?;
    let (w, h) = (image.width, image.height);
    let Some(level) = image.reader.levels().next() else {
        return Err("KTX2 has no level".into());
    };
    let basis = match image.kind {
        Kind::Uastc { zstd, alpha } => {
            let blocks = u64::from(w.div_ceil(4)) * u64::from(h.div_ceil(4));
            let expected = blocks * 16;
            let inflated;
            let data = if zstd {
                if level.uncompressed_byte_length != expected {
                    return Err(format!(
                        "KTX2 level 0 says it inflates to {} bytes, not the {expected} of its {blocks} UASTC blocks",
                        level.uncompressed_byte_length
                    ));
                }
                inflated = inflate(level.data, expected as usize)?;
                &inflated[..]
            } else {
                level.data
            };
            if data.len() as u64 != expected {
                return Err(format!(
                    "KTX2 level 0 holds {} bytes, not the {expected} of its {blocks} UASTC blocks",
                    data.len()
                ));
            }
            basis_file(&Basis { uastc: true, alpha, w, h, books: None, slices: &[data] })?
        }
        Kind::Etc1s => {
            // One image descriptor per level (a single 2D image has no layers or faces).
            let images = image.reader.header().level_count.max(1);
            let sgd = image.reader.supercompression_global_data();
            etc1s_as_basis(sgd, images, level.data, w, h)?
        }
    };
    let mut transcoder = Transcoder::new();
    transcoder.prepare_transcoding(&basis).map_err(|()| {
        "cannot read the Basis Universal data (codebooks or header): corrupt or truncated"
            .to_string()
    })?;
    let params = TranscodeParameters { image_index: 0, level_index: 0, ..Default::default() };
    let rgba =
        transcoder.transcode_image_level(&basis, TranscoderTextureFormat::RGBA32, params).map_err(
            |e| format!("cannot transcode the Basis Universal data ({e:?}): corrupt or truncated"),
        );
    transcoder.end_transcoding();
    let rgba = rgba?;
    if rgba.len() as u64 != u64::from(w) * u64::from(h) * 4 {
        return Err(format!("transcoded to {} bytes, not {w}x{h} RGBA texels", rgba.len()));
    }
    Ok(rgba.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect())
}

/// Inflates a Zstandard level into exactly `expected` bytes: more is an error before it is
/// written, and the decoder's window is bounded by what the level can need.
fn inflate(data: &[u8], expected: usize) -> Result<Vec<u8>, String> {
    let mut decoder = ruzstd::decoding::FrameDecoder::new();
    decoder.set_max_window_size((expected as u64).max(1 << 20));
    let mut out = vec![0u8; expected];
    let written = decoder
        .decode_all(data, &mut out)
        .map_err(|e| format!("cannot inflate the Zstandard level: {e}"))?;
    if written != expected {
        return Err(format!("the Zstandard level inflates to {written} bytes, not {expected}"));
    }
    Ok(out)
}

/// Little-endian integers of `n` bytes at `at` of `b` (checked by the caller).
fn le(b: &[u8], at: usize, n: usize) -> u64 {
    b[at..at + n].iter().rev().fold(0, |v, &x| v << 8 | u64::from(x))
}

/// The `.basis` file that holds an ETC1S KTX2 image's level 0: `sgd` is the KTX2's BasisLZ
/// global data (codebooks, Huffman tables and one image descriptor per image, `images` of them,
/// level 0's first), `level` the bytes of its level 0.
fn etc1s_as_basis(
    sgd: &[u8],
    images: u32,
    level: &[u8],
    w: u32,
    h: u32,
) -> Result<Vec<u8>, String> {
    // The global data: a 20-byte header, a 20-byte image descriptor per image, then the endpoint
    // and selector codebooks, the tables and the extended data.
    const HEADER: u64 = 20;
    const DESC: u64 = 20;
    if (sgd.len() as u64) < HEADER + DESC {
        return Err(format!("KTX2 BasisLZ global data of {} bytes is truncated", sgd.len()));
    }
    let endpoint_count = le(sgd, 0, 2);
    let selector_count = le(sgd, 2, 2);
    let lengths = [le(sgd, 4, 4), le(sgd, 8, 4), le(sgd, 12, 4)];
    let needed = HEADER + DESC * u64::from(images) + lengths.iter().sum::<u64>() + le(sgd, 16, 4);
    if needed > sgd.len() as u64 {
        return Err(format!(
            "KTX2 BasisLZ global data of {} bytes is shorter than the {needed} its lengths add up to",
            sgd.len()
        ));
    }
    let desc = HEADER as usize;
    let rgb = (le(sgd, desc + 4, 4), le(sgd, desc + 8, 4));
    let alpha = (le(sgd, desc + 12, 4), le(sgd, desc + 16, 4));
    if endpoint_count == 0 || selector_count == 0 || lengths.contains(&0) || rgb.1 == 0 {
        return Err("KTX2 BasisLZ global data has empty codebooks or slices".into());
    }
    if lengths[0] >= 1 << 24 || lengths[1] >= 1 << 24 {
        return Err("KTX2 BasisLZ codebooks too large for Basis Universal".into());
    }
    let slice_of = |(offset, length): (u64, u64)| -> Result<&[u8], String> {
        offset
            .checked_add(length)
            .filter(|&end| end <= level.len() as u64)
            .map(|end| &level[offset as usize..end as usize])
            .ok_or_else(|| {
                format!("KTX2 slice {offset}..+{length} overruns level 0 ({} bytes)", level.len())
            })
    };
    let mut slices = vec![slice_of(rgb)?];
    if alpha.1 > 0 {
        slices.push(slice_of(alpha)?);
    }
    let mut at = (HEADER + DESC * u64::from(images)) as usize;
    let mut books = [&sgd[..0]; 3];
    for (book, &len) in books.iter_mut().zip(&lengths) {
        *book = &sgd[at..at + len as usize];
        at += len as usize;
    }
    let books = Codebooks { parts: books, endpoints: endpoint_count, selectors: selector_count };
    basis_file(&Basis {
        uastc: false,
        alpha: alpha.1 > 0,
        w,
        h,
        books: Some(books),
        slices: &slices,
    })
}

/// What a one-image `.basis` file holds.
struct Basis<'a> {
    /// UASTC blocks, else ETC1S.
    uastc: bool,
    alpha: bool,
    w: u32,
    h: u32,
    /// ETC1S's codebooks.
    books: Option<Codebooks<'a>>,
    /// The image's slices: its colour (ETC1S) or blocks (UASTC), then ETC1S's alpha.
    slices: &'a [&'a [u8]],
}

/// ETC1S's endpoint and selector codebooks and Huffman tables, and how many endpoints and
/// selectors there are.
struct Codebooks<'a> {
    parts: [&'a [u8]; 3],
    endpoints: u64,
    selectors: u64,
}

/// A `.basis` file (format version 0x13) of one image: header, slice descriptors, codebooks,
/// tables, slices.
fn basis_file(b: &Basis<'_>) -> Result<Vec<u8>, String> {
    const HEADER: usize = 77;
    const SLICE_DESC: usize = 23;
    let (books, endpoints, selectors) =
        b.books.as_ref().map_or(([&[][..]; 3], 0, 0), |c| (c.parts, c.endpoints, c.selectors));
    let descs_at = HEADER;
    let mut at = descs_at + b.slices.len() * SLICE_DESC;
    let mut books_at = [0; 3];
    for (o, book) in books_at.iter_mut().zip(&books) {
        *o = at;
        at += book.len();
    }
    let mut slices_at = Vec::with_capacity(b.slices.len());
    for slice in b.slices {
        slices_at.push(at);
        at += slice.len();
    }
    let total = at;
    if total > u32::MAX as usize {
        return Err("KTX2 image too large for Basis Universal".into());
    }
    let put =
        |out: &mut Vec<u8>, v: u64, n: usize| out.extend((0..n).map(|i| (v >> (8 * i)) as u8));
    let mut out = vec![0u8; HEADER];
    for (k, (slice, &at)) in b.slices.iter().zip(&slices_at).enumerate() {
        let has_alpha = if b.uastc { b.alpha } else { k == 1 };
        put(&mut out, 0, 3); // image index
        put(&mut out, 0, 1); // level index
        put(&mut out, u64::from(has_alpha), 1); // flags: has alpha
        put(&mut out, u64::from(b.w), 2);
        put(&mut out, u64::from(b.h), 2);
        put(&mut out, u64::from(b.w.div_ceil(4)), 2);
        put(&mut out, u64::from(b.h.div_ceil(4)), 2);
        put(&mut out, at as u64, 4);
        put(&mut out, slice.len() as u64, 4);
        put(&mut out, 0, 2); // slice CRC, unchecked by the transcoder
    }
    for part in books.iter().chain(b.slices) {
        out.extend_from_slice(part);
    }
    debug_assert_eq!(out.len(), total);
    let data_crc = crc16(&out[HEADER..]);
    let mut header = Vec::with_capacity(HEADER);
    put(&mut header, 0x4273, 2); // "sB"
    put(&mut header, 0x13, 2); // the format version the transcoder reads
    put(&mut header, HEADER as u64, 2);
    put(&mut header, 0, 2); // header CRC, below
    put(&mut header, (total - HEADER) as u64, 4);
    put(&mut header, u64::from(data_crc), 2);
    put(&mut header, b.slices.len() as u64, 3);
    put(&mut header, 1, 3); // images
    put(&mut header, u64::from(b.uastc), 1); // 0 ETC1S, 1 UASTC 4x4
                                             // Flags: ETC1S 1, has alpha slices 4.
    put(&mut header, u64::from(!b.uastc) | if b.alpha { 4 } else { 0 }, 2);
    put(&mut header, 0, 1); // 2D
    put(&mut header, 0, 3 + 4 + 4 + 4); // us per frame, reserved, user data
    put(&mut header, endpoints, 2);
    put(&mut header, books_at[0] as u64, 4);
    put(&mut header, books[0].len() as u64, 3);
    put(&mut header, selectors, 2);
    put(&mut header, books_at[1] as u64, 4);
    put(&mut header, books[1].len() as u64, 3);
    put(&mut header, books_at[2] as u64, 4);
    put(&mut header, books[2].len() as u64, 4);
    put(&mut header, descs_at as u64, 4);
    put(&mut header, 0, 4 + 4); // no extended data
    debug_assert_eq!(header.len(), HEADER);
    let header_crc = crc16(&header[8..]);
    header[6..8].copy_from_slice(&header_crc.to_le_bytes());
    out[..HEADER].copy_from_slice(&header);
    Ok(out)
}

/// The CRC-16 of `.basis` files (Basis Universal's `crc16`, initial value 0).
fn crc16(bytes: &[u8]) -> u16 {
    let mut crc: u16 = !0;
    for &b in bytes {
        let q = u16::from(b) ^ (crc >> 8);
        let k = (q >> 4) ^ q;
        crc = (((crc << 8) ^ k) ^ (k << 5)) ^ (k << 12);
    }
    !crc
}
