//! `GET /api/v1/jobs/{id}/frames/{n}.exr` (or `.png`, with `?exposure=STOPS&tonemap=NAME`): a
//! frame's image, also while its job runs; `GET /api/v1/jobs/{id}/frames/{n}/tiles`: its tiles'
//! samples and estimated error (the dashboard's heat map).
//!
//! A frame is read a tile at a time, from memory under the farm's lock for one tile's copy at a
//! time, or, once its job finished and its sums left memory, from the database on a connection
//! of its own without the lock. Nothing holds a whole frame: the EXR is written a row of tiles
//! at a time into an unnamed file in the data folder and streamed from it; the PNG preview is
//! downscaled past [`PREVIEW_MAX_SIDE`](crate::output::PREVIEW_MAX_SIDE). A frame of a running
//! job may show tiles at slightly different moments.

use axum::{
    body::Body,
    extract::{Path, State},
    http::{header, HeaderValue},
    response::{IntoResponse, Response},
};
use common::film::TileAccum;

use super::{
    blocking, file_chunks,
    jobs::{query_pairs, QueryPairs},
    ApiResult, AppState,
};
use crate::{
    farm::{store::TileReader, FarmError, FrameLayout, TileCopy},
    output::{write_exr_in_bands, ExrTotals, FrameImage, Preview, ToneMap},
};

/// The most stops a preview's exposure may take either way.
const MAX_EXPOSURE: f32 = 20.0;

/// A PNG preview's `exposure` (stops, default 0) and `tonemap` (default `clamp`); other keys
/// (a cache buster) are ignored.
fn preview_options(pairs: Vec<(String, String)>) -> ApiResult<(f32, ToneMap)> {
    let (mut exposure, mut tone) = (0.0, ToneMap::Clamp);
    for (key, value) in pairs {
        match key.as_str() {
            "exposure" => {
                exposure = value
                    .parse::<f32>()
                    .ok()
                    .filter(|e| e.abs() <= MAX_EXPOSURE)
                    .ok_or_else(|| {
                        FarmError::malformed(format!(
                            "exposure: '{value}' is not a number of stops from -{MAX_EXPOSURE} to {MAX_EXPOSURE}"
                        ))
                    })?;
            }
            "tonemap" => {
                tone = ToneMap::parse(&value).ok_or_else(|| {
                    FarmError::malformed(format!(
                        "tonemap: '{value}' is not one of {}",
                        ToneMap::NAMES.join(", ")
                    ))
                })?;
            }
            _ => {}
        }
    }
    Ok((exposure, tone))
}

pub(super) async fn frame_image(
    State(state): State<AppState>,
    Path((id, file)): Path<(String, String)>,
    query: QueryPairs,
) -> ApiResult<Response> {
    let (number, ext) = file
        .rsplit_once('.')
        .and_then(|(n, e)| Some((n.parse::<i64>().ok()?, e.to_ascii_lowercase())))
        .ok_or_else(|| {
            FarmError::not_found(format!(
                "'{file}' is not a frame file: use {{n}}.exr or {{n}}.png"
            ))
        })?;
    match ext.as_str() {
        "png" => {
            let options = preview_options(query_pairs(query)?)?;
            let png = blocking(move || preview(&state, &id, number, options)).await?;
            Ok(([(header::CONTENT_TYPE, HeaderValue::from_static("image/png"))], png)
                .into_response())
        }
        "exr" => {
            let (file, len) = blocking(move || exr_file(&state, &id, number)).await?;
            Ok((
                [
                    (header::CONTENT_TYPE, HeaderValue::from_static("image/x-exr")),
                    (header::CONTENT_LENGTH, HeaderValue::from(len)),
                ],
                Body::from_stream(file_chunks(tokio::fs::File::from_std(file))),
            )
                .into_response())
        }
        _ => Err(FarmError::not_found(format!("'{file}': frames are served as .exr or .png"))),
    }
}

/// A frame's tiles, read one at a time.
struct FrameTiles<'a> {
    state: &'a AppState,
    layout: FrameLayout,
    /// Set once the frame's sums are found to be in the database.
    reader: Option<TileReader>,
    /// Bidirectional path tracing's light tile, the whole frame, read once: its pixels add to
    /// every tile's.
    light: Option<TileAccum>,
}

impl<'a> FrameTiles<'a> {
    fn open(state: &'a AppState, id: &str, number: i64) -> ApiResult<Self> {
        let layout = state.lock().frame_layout(id, number)?;
        let reader = if layout.stored { Some(state.lock().tile_reader()?) } else { None };
        let light_tile = layout.light_tile;
        let mut tiles = FrameTiles { state, layout, reader, light: None };
        if let Some(t) = light_tile {
            tiles.light = tiles.sums(t)?;
        }
        Ok(tiles)
    }

    /// Tile `t` of the image (a tile of `layout.tiles`), `None` when it has no sums yet.
    fn tile(&mut self, t: usize) -> ApiResult<Option<TileAccum>> {
        let own = self.sums(t)?;
        Ok(match (&self.light, own) {
            (Some(light), own) => {
                let rect = self.layout.tiles[t];
                let own = own.unwrap_or(TileAccum { rect, pixels: Vec::new(), rejected: 0 });
                Some(own.plus_frame_wide(light))
            }
            (None, own) => own,
        })
    }

    /// The merged sums of tile index `t` of the frame, `None` when it has none yet.
    fn sums(&mut self, t: usize) -> ApiResult<Option<TileAccum>> {
        if self.reader.is_none() {
            let copy = self.state.lock().tile_copy(&self.layout.job, self.layout.f, t)?;
            match copy {
                TileCopy::Sums(sums) => return Ok(Some(sums)),
                TileCopy::Empty => return Ok(None),
                // The job finished meanwhile: the rest is read from the database.
                TileCopy::Stored => self.reader = Some(self.state.lock().tile_reader()?),
            }
        }
        let reader = self.reader.as_ref().expect("a reader was just opened");
        Ok(reader.tile(&self.layout.job, self.layout.f as u32, t as u32)?)
    }
}

/// The PNG preview of a frame, built a tile at a time.
fn preview(
    state: &AppState,
    id: &str,
    number: i64,
    (exposure, tone): (f32, ToneMap),
) -> ApiResult<Vec<u8>> {
    let mut tiles = FrameTiles::open(state, id, number)?;
    let (width, height) = tiles.layout.size;
    let mut preview = Preview::new(width, height);
    for t in 0..tiles.layout.tiles.len() {
        if let Some(tile) = tiles.tile(t)? {
            preview.add_tile(&tile);
        }
    }
    Ok(preview.png_mapped(exposure, tone)?)
}

/// `GET /api/v1/jobs/{id}/frames/{n}/tiles`: each tile's rectangle, tasks merged, samples per
/// pixel and estimated relative error.
pub(super) async fn frame_tiles(
    State(state): State<AppState>,
    Path((id, number)): Path<(String, String)>,
) -> ApiResult<Response> {
    let number = number
        .parse::<i64>()
        .map_err(|_| FarmError::not_found(format!("'{number}' is not a frame number")))?;
    let map = state.lock().tile_map(&id, number)?;
    Ok(axum::Json(map).into_response())
}

/// The EXR of a frame, written a row of tiles at a time into an unnamed file (gone when it is
/// closed) in the data folder, rewound; and its length.
fn exr_file(state: &AppState, id: &str, number: i64) -> ApiResult<(std::fs::File, u64)> {
    use std::io::{Seek, SeekFrom};
    let mut tiles = FrameTiles::open(state, id, number)?;
    // The header comes first and states totals over the whole frame: one pass for them.
    let mut totals = ExrTotals::default();
    totals.rejected += tiles.light.as_ref().map_or(0, |l| l.rejected);
    for t in 0..tiles.layout.tiles.len() {
        if let Some(tile) = tiles.tile(t)? {
            totals.add_tile(&tile);
        }
    }
    let dir = state.lock().config().data_dir.clone();
    let mut file = tempfile::tempfile_in(&dir).map_err(|e| {
        FarmError::internal(format!("a file for the EXR in {}: {e}", dir.display()))
    })?;
    let layout = tiles.layout.clone();
    let (width, _) = layout.size;
    // Tiles start at multiples of the band's height: each lies in one band.
    write_exr_in_bands(
        &mut file,
        layout.size,
        &layout.info,
        &totals,
        layout.tile_rows,
        |y0, rows| {
            let mut band = FrameImage::new(width, rows);
            // The tiles are row-major: the band's are one run of them, found by bisection (a
            // scan per band would cost tiles x bands, 268 M steps for a 16k frame).
            let first = layout.tiles.partition_point(|r| r.y0 < y0);
            let end = layout.tiles.partition_point(|r| r.y0 < y0 + rows);
            for t in first..end {
                if let Some(tile) = tiles.tile(t).map_err(|e| anyhow::anyhow!(e.message))? {
                    band.put_tile_below(&tile, y0);
                }
            }
            Ok(band)
        },
    )?;
    let len = file.seek(SeekFrom::End(0)).map_err(|e| FarmError::internal(e.to_string()))?;
    file.rewind().map_err(|e| FarmError::internal(e.to_string()))?;
    Ok((file, len))
}
