//! Buffers, buffer views and accessors: loads buffer bytes on first use (GLB chunk, `data:` URI
//! or resolver), and reads accessors with every bound checked — strides, offsets, matrix column
//! padding, normalised integers, accessors without a buffer view, and sparse substitution.

use std::borrow::Cow;

use ::gltf::json;
use json::accessor::{ComponentType, Type};
use json::validation::Checked;

use super::meshopt;
use super::uri::{self, Source};
use super::{fail, Context, Loader, SceneError};
use crate::budget;

/// The most components (not bytes) one accessor may expand to; guards allocations of accessors
/// whose elements are not backed by a buffer (all zeros, or sparse).
const MAX_COMPONENTS: u64 = 1 << 28;

/// The layout of an accessor's data, checked against the file.
#[derive(Clone, Copy, Debug)]
pub(crate) struct AccessorInfo {
    pub(crate) count: usize,
    pub(crate) ty: Type,
    pub(crate) component: ComponentType,
    pub(crate) normalized: bool,
}

impl AccessorInfo {
    /// Number of components per element.
    pub(crate) fn components(&self) -> usize {
        components(self.ty)
    }

    /// A description such as "VEC3 of unsigned short", for messages.
    pub(crate) fn describe(&self) -> String {
        format!(
            "{} of {}{}",
            type_name(self.ty),
            if self.normalized { "normalized " } else { "" },
            component_name(self.component)
        )
    }
}

fn components(ty: Type) -> usize {
    match ty {
        Type::Scalar => 1,
        Type::Vec2 => 2,
        Type::Vec3 => 3,
        Type::Vec4 | Type::Mat2 => 4,
        Type::Mat3 => 9,
        Type::Mat4 => 16,
    }
}

fn type_name(ty: Type) -> &'static str {
    match ty {
        Type::Scalar => "SCALAR",
        Type::Vec2 => "VEC2",
        Type::Vec3 => "VEC3",
        Type::Vec4 => "VEC4",
        Type::Mat2 => "MAT2",
        Type::Mat3 => "MAT3",
        Type::Mat4 => "MAT4",
    }
}

fn component_name(c: ComponentType) -> &'static str {
    match c {
        ComponentType::I8 => "byte",
        ComponentType::U8 => "unsigned byte",
        ComponentType::I16 => "short",
        ComponentType::U16 => "unsigned short",
        ComponentType::U32 => "unsigned int",
        ComponentType::F32 => "float",
    }
}

pub(crate) fn component_size(c: ComponentType) -> usize {
    match c {
        ComponentType::I8 | ComponentType::U8 => 1,
        ComponentType::I16 | ComponentType::U16 => 2,
        ComponentType::U32 | ComponentType::F32 => 4,
    }
}

/// Byte offsets of the components of one element inside it, and the element's size (matrix
/// columns start on 4-byte boundaries, spec 3.6.2.4).
fn element_layout(ty: Type, component: ComponentType) -> (Vec<usize>, usize) {
    let size = component_size(component);
    let (rows, cols) = match ty {
        Type::Mat2 => (2, 2),
        Type::Mat3 => (3, 3),
        Type::Mat4 => (4, 4),
        other => (components(other), 1),
    };
    let column_bytes = if cols > 1 { (rows * size).div_ceil(4) * 4 } else { rows * size };
    let offsets = (0..rows * cols).map(|c| (c / rows) * column_bytes + (c % rows) * size).collect();
    (offsets, cols * column_bytes)
}

/// Decodes one component into the output type.
pub(crate) trait ComponentValue: Copy + Default {
    /// Reads one little-endian component from the start of `bytes` (long enough, checked).
    fn decode(component: ComponentType, normalized: bool, bytes: &[u8]) -> Self;
}

fn le_u16(b: &[u8]) -> u16 {
    u16::from_le_bytes([b[0], b[1]])
}

fn le_u32(b: &[u8]) -> u32 {
    u32::from_le_bytes([b[0], b[1], b[2], b[3]])
}

impl ComponentValue for f32 {
    fn decode(component: ComponentType, normalized: bool, b: &[u8]) -> f32 {
        match (component, normalized) {
            (ComponentType::F32, _) => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            // Spec 3.11: normalised integer to float.
            (ComponentType::I8, true) => (b[0] as i8 as f32 / 127.0).max(-1.0),
            (ComponentType::U8, true) => b[0] as f32 / 255.0,
            (ComponentType::I16, true) => (le_u16(b) as i16 as f32 / 32767.0).max(-1.0),
            (ComponentType::U16, true) => le_u16(b) as f32 / 65535.0,
            (ComponentType::U32, true) => (le_u32(b) as f64 / u32::MAX as f64) as f32,
            (ComponentType::I8, false) => b[0] as i8 as f32,
            (ComponentType::U8, false) => b[0] as f32,
            (ComponentType::I16, false) => le_u16(b) as i16 as f32,
            (ComponentType::U16, false) => le_u16(b) as f32,
            (ComponentType::U32, false) => le_u32(b) as f32,
        }
    }
}

impl ComponentValue for u32 {
    /// Only for unsigned integer accessors (checked by the caller).
    fn decode(component: ComponentType, _normalized: bool, b: &[u8]) -> u32 {
        match component {
            ComponentType::U8 => b[0] as u32,
            ComponentType::U16 => le_u16(b) as u32,
            ComponentType::U32 => le_u32(b),
            ComponentType::I8 => b[0] as i8 as u32,
            ComponentType::I16 => le_u16(b) as i16 as u32,
            ComponentType::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as u32,
        }
    }
}

impl<'a> Loader<'a> {
    /// The bytes of buffer `index`, loaded on first use and cut to its `byteLength`.
    pub(crate) fn buffer(&self, index: usize) -> Result<&[u8], SceneError> {
        let Some(cell) = self.buffers.get(index) else {
            return fail(format!(
                "buffer {index}: does not exist (the file has {} buffers)",
                self.buffers.len()
            ));
        };
        if cell.get().is_none() {
            let data = self.load_buffer(index).context(|| format!("buffer {index}"))?;
            let _ = cell.set(data);
        }
        match cell.get() {
            Some(data) => Ok(data),
            None => fail(format!("buffer {index}: could not be loaded")),
        }
    }

    fn load_buffer(&self, index: usize) -> Result<Cow<'a, [u8]>, SceneError> {
        let buffer = &self.root.buffers[index];
        let declared = buffer.byte_length.0;
        let data: Cow<'a, [u8]> = match (&buffer.uri, index, self.bin) {
            (Some(uri), _, _) => Cow::Owned(self.fetch(uri)?),
            (None, 0, Some(bin)) => Cow::Borrowed(bin),
            (None, 0, None) if declared == 0 => Cow::Borrowed(&[]),
            (None, _, _) if meshopt_fallback(buffer) => {
                return fail(format!(
                    "is an {} fallback buffer without a uri: only buffer views that carry the extension may refer to it",
                    meshopt::EXTENSION
                ))
            }
            (None, 0, None) => return fail("has no uri and the file has no GLB BIN chunk"),
            (None, _, _) => return fail("has no uri (only buffer 0 of a .glb may omit it)"),
        };
        if (data.len() as u64) < declared {
            return fail(format!("has {} bytes but its byteLength is {declared}", data.len()));
        }
        let declared = declared as usize;
        Ok(match data {
            Cow::Borrowed(b) => Cow::Borrowed(&b[..declared]),
            Cow::Owned(mut v) => {
                v.truncate(declared);
                Cow::Owned(v)
            }
        })
    }

    /// The bytes a buffer or image URI names.
    pub(crate) fn fetch(&self, uri: &str) -> Result<Vec<u8>, SceneError> {
        match uri::classify(uri).map_err(SceneError)? {
            Source::Data(bytes) => Ok(bytes),
            Source::File(path) => self.files.read(&path).map_err(|e| {
                if e.contains(&path) {
                    SceneError(e)
                } else {
                    SceneError(format!("'{path}': {e}"))
                }
            }),
        }
    }

    /// The bytes of buffer view `index` (checked against its buffer) and its byteStride.
    pub(crate) fn view(&self, index: usize) -> Result<(&[u8], Option<usize>), SceneError> {
        let Some(view) = self.root.buffer_views.get(index) else {
            return fail(format!(
                "buffer view {index}: does not exist (the file has {} buffer views)",
                self.root.buffer_views.len()
            ));
        };
        if let Some(ext) = view.extensions.as_ref().and_then(|e| e.others.get(meshopt::EXTENSION)) {
            let bytes = self
                .decoded_view(index, view, ext)
                .context(|| format!("buffer view {index}: {}", meshopt::EXTENSION))?;
            return Ok((bytes, view.byte_stride.map(|s| s.0)));
        }
        let buffer = self.buffer(view.buffer.value())?;
        let offset = view.byte_offset.map_or(0, |o| o.0);
        let length = view.byte_length.0;
        let end = offset.checked_add(length).filter(|&e| e <= buffer.len() as u64);
        let Some(end) = end else {
            return fail(format!(
                "buffer view {index}: bytes {offset}..{} overrun buffer {} ({} bytes)",
                offset as u128 + length as u128,
                view.buffer.value(),
                buffer.len()
            ));
        };
        Ok((&buffer[offset as usize..end as usize], view.byte_stride.map(|s| s.0)))
    }

    /// The bytes of buffer view `index` decoded from the compressed bytes its
    /// `EXT_meshopt_compression` object `ext` names, on first use; the decoded size is charged to
    /// the scene's budget before anything is decoded.
    fn decoded_view(
        &self,
        index: usize,
        view: &json::buffer::View,
        ext: &serde_json::Value,
    ) -> Result<&[u8], SceneError> {
        if let Some(bytes) = self.decoded_views[index].get() {
            return Ok(bytes);
        }
        let c = meshopt::parse(ext, view.byte_length.0, view.byte_stride.map(|s| s.0))
            .map_err(SceneError)?;
        self.charge_scene(budget::Line::InflatedBytes, c.decoded_len(), || {
            format!("buffer view {index}, {} x {} bytes decoded", c.count, c.stride)
        })?;
        let buffer = self.buffer(c.buffer)?;
        let Some(src) = slice_checked(buffer, c.offset, c.length) else {
            return fail(format!(
                "compressed bytes {}..{} overrun buffer {} ({} bytes)",
                c.offset,
                c.offset as u128 + c.length as u128,
                c.buffer,
                buffer.len()
            ));
        };
        let decoded = meshopt::decode(&c, src).map_err(SceneError)?;
        Ok(self.decoded_views[index].get_or_init(|| decoded))
    }

    /// The checked header of accessor `index`.
    pub(crate) fn accessor_info(&self, index: usize) -> Result<AccessorInfo, SceneError> {
        let Some(acc) = self.root.accessors.get(index) else {
            return fail(format!(
                "accessor {index}: does not exist (the file has {} accessors)",
                self.root.accessors.len()
            ));
        };
        let Checked::Valid(component) = acc.component_type else {
            return fail(format!("accessor {index}: invalid componentType"));
        };
        let Checked::Valid(ty) = acc.type_ else {
            return fail(format!("accessor {index}: invalid type"));
        };
        let count = acc.count.0;
        if count.saturating_mul(components(ty) as u64) > MAX_COMPONENTS {
            return fail(format!("accessor {index}: count {count} is too large"));
        }
        Ok(AccessorInfo {
            count: count as usize,
            ty,
            component: component.0,
            normalized: acc.normalized,
        })
    }

    /// Reads accessor `index` as floats (normalised integers mapped as the spec says, other
    /// integers converted), `components()` values per element.
    pub(crate) fn read_f32(&self, index: usize) -> Result<(AccessorInfo, Vec<f32>), SceneError> {
        self.read::<f32>(index)
    }

    /// Reads a SCALAR unsigned-integer accessor (vertex indices).
    pub(crate) fn read_indices(&self, index: usize) -> Result<Vec<u32>, SceneError> {
        let info = self.accessor_info(index)?;
        let unsigned =
            matches!(info.component, ComponentType::U8 | ComponentType::U16 | ComponentType::U32);
        if info.ty != Type::Scalar || !unsigned || info.normalized {
            return fail(format!(
                "accessor {index}: indices must be SCALAR of unsigned byte, short or int, not {}",
                info.describe()
            ));
        }
        Ok(self.read::<u32>(index)?.1)
    }

    fn read<T: ComponentValue>(&self, index: usize) -> Result<(AccessorInfo, Vec<T>), SceneError> {
        let info = self.accessor_info(index)?;
        let acc = &self.root.accessors[index];
        let (offsets, elem_size) = element_layout(info.ty, info.component);
        let n = offsets.len();
        let csize = component_size(info.component);
        self.charge(
            (info.count * n) as u64,
            |b| &mut b.components,
            || format!("accessor {index}"),
        )?;
        let mut out: Vec<T>;
        let draco = self.draco.borrow().get(&index).cloned();
        if let Some(bytes) = draco {
            // Decoded from the primitive's Draco stream: tightly packed, `count` elements.
            if bytes.len() != info.count * elem_size {
                return fail(format!("accessor {index}: Draco data of the wrong size"));
            }
            out = Vec::with_capacity(info.count * n);
            for element in bytes.chunks_exact(elem_size) {
                for &o in &offsets {
                    out.push(T::decode(info.component, info.normalized, &element[o..o + csize]));
                }
            }
        } else if let Some(view_index) = acc.buffer_view {
            let (bytes, stride) =
                self.view(view_index.value()).context(|| format!("accessor {index}"))?;
            let stride = stride.unwrap_or(elem_size);
            if stride < elem_size {
                return fail(format!(
                    "accessor {index}: byteStride {stride} of buffer view {} is smaller than the element size {elem_size}",
                    view_index.value()
                ));
            }
            let offset = acc.byte_offset.map_or(0, |o| o.0);
            if info.count > 0 {
                let needed = (info.count as u64 - 1)
                    .checked_mul(stride as u64)
                    .and_then(|x| x.checked_add(elem_size as u64))
                    .and_then(|x| x.checked_add(offset));
                if needed.is_none_or(|needed| needed > bytes.len() as u64) {
                    return fail(format!(
                        "accessor {index}: {} elements of {elem_size} bytes (stride {stride}) from byte {offset} overrun buffer view {} ({} bytes)",
                        info.count,
                        view_index.value(),
                        bytes.len()
                    ));
                }
            }
            let bytes = bytes.get(offset as usize..).unwrap_or(&[]);
            out = Vec::with_capacity(info.count * n);
            for i in 0..info.count {
                let element = &bytes[i * stride..i * stride + elem_size];
                for &o in &offsets {
                    out.push(T::decode(info.component, info.normalized, &element[o..o + csize]));
                }
            }
        } else {
            if acc.sparse.is_none() {
                tracing::debug!("accessor {index}: no bufferView and not sparse; all zeros");
            }
            out = vec![T::default(); info.count * n];
        }
        if let Some(sparse) = &acc.sparse {
            self.apply_sparse(index, &info, sparse, &offsets, elem_size, &mut out)?;
        }
        Ok((info, out))
    }

    fn apply_sparse<T: ComponentValue>(
        &self,
        index: usize,
        info: &AccessorInfo,
        sparse: &json::accessor::sparse::Sparse,
        offsets: &[usize],
        elem_size: usize,
        out: &mut [T],
    ) -> Result<(), SceneError> {
        let count = sparse.count.0;
        if count > info.count as u64 {
            return fail(format!(
                "accessor {index}: sparse count {count} exceeds the accessor's count {}",
                info.count
            ));
        }
        let count = count as usize;
        let Checked::Valid(index_type) = sparse.indices.component_type else {
            return fail(format!("accessor {index}: invalid sparse indices componentType"));
        };
        let index_type = index_type.0;
        let isize = component_size(index_type);
        let (ibytes, _) = self
            .view(sparse.indices.buffer_view.value())
            .context(|| format!("accessor {index}: sparse indices"))?;
        let ioff = sparse.indices.byte_offset.0;
        let ibytes = slice_checked(ibytes, ioff, count as u64 * isize as u64).ok_or_else(|| {
            SceneError(format!(
                "accessor {index}: {count} sparse indices from byte {ioff} overrun buffer view {} ({} bytes)",
                sparse.indices.buffer_view.value(),
                ibytes.len()
            ))
        })?;
        let (vbytes, _) = self
            .view(sparse.values.buffer_view.value())
            .context(|| format!("accessor {index}: sparse values"))?;
        let voff = sparse.values.byte_offset.0;
        let vbytes = slice_checked(vbytes, voff, count as u64 * elem_size as u64).ok_or_else(|| {
            SceneError(format!(
                "accessor {index}: {count} sparse values from byte {voff} overrun buffer view {} ({} bytes)",
                sparse.values.buffer_view.value(),
                vbytes.len()
            ))
        })?;
        let n = offsets.len();
        let csize = component_size(info.component);
        for k in 0..count {
            let target = u32::decode(index_type, false, &ibytes[k * isize..]) as usize;
            if target >= info.count {
                return fail(format!(
                    "accessor {index}: sparse index {target} out of range for {} elements",
                    info.count
                ));
            }
            let element = &vbytes[k * elem_size..(k + 1) * elem_size];
            for (c, &o) in offsets.iter().enumerate() {
                out[target * n + c] =
                    T::decode(info.component, info.normalized, &element[o..o + csize]);
            }
        }
        Ok(())
    }
}

/// Whether `buffer` is tagged as an `EXT_meshopt_compression` fallback buffer: its bytes exist
/// only as the decoded views that refer to it.
fn meshopt_fallback(buffer: &json::Buffer) -> bool {
    let ext = buffer.extensions.as_ref().and_then(|e| e.others.get(meshopt::EXTENSION));
    ext.and_then(|e| e.get("fallback")).and_then(serde_json::Value::as_bool) == Some(true)
}

/// `bytes[offset..offset + len]`, if it fits.
fn slice_checked(bytes: &[u8], offset: u64, len: u64) -> Option<&[u8]> {
    let end = offset.checked_add(len)?;
    if end > bytes.len() as u64 {
        return None;
    }
    bytes.get(offset as usize..end as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalisation_follows_the_spec() {
        assert_eq!(f32::decode(ComponentType::I8, true, &[0x81]), -1.0);
        assert_eq!(f32::decode(ComponentType::I8, true, &[0x80]), -1.0);
        assert_eq!(f32::decode(ComponentType::I8, true, &[127]), 1.0);
        assert_eq!(f32::decode(ComponentType::U8, true, &[255]), 1.0);
        assert_eq!(f32::decode(ComponentType::I16, true, &0x8000u16.to_le_bytes()), -1.0);
        assert_eq!(f32::decode(ComponentType::U16, true, &65535u16.to_le_bytes()), 1.0);
        assert_eq!(f32::decode(ComponentType::I16, false, &(-5i16).to_le_bytes()), -5.0);
        assert_eq!(u32::decode(ComponentType::U16, false, &513u16.to_le_bytes()), 513);
    }

    #[test]
    fn matrix_columns_are_padded() {
        assert_eq!(element_layout(Type::Mat2, ComponentType::U8), (vec![0, 1, 4, 5], 8));
        assert_eq!(element_layout(Type::Mat3, ComponentType::I16).1, 24);
        assert_eq!(element_layout(Type::Mat4, ComponentType::F32).1, 64);
        assert_eq!(element_layout(Type::Vec3, ComponentType::U8), (vec![0, 1, 2], 3));
    }
}
