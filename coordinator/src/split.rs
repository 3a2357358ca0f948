//! Splitting a frame into tasks: tiles x sample ranges, ordered so that the image refines
//! progressively (every tile gets its first samples before any tile gets more).

use common::{
    film::Rect,
    protocol::{SampleRange, TaskSpec},
    settings::RenderSettings,
};

/// The tiles of a `width` x `height` image, row-major, edge tiles clipped.
pub fn tiles(width: u32, height: u32, tile_size: u32) -> Vec<Rect> {
    let mut out = Vec::new();
    let mut y0 = 0;
    while y0 < height {
        let mut x0 = 0;
        while x0 < width {
            out.push(Rect {
                x0,
                y0,
                width: tile_size.min(width - x0),
                height: tile_size.min(height - y0),
            });
            x0 += tile_size;
        }
        y0 += tile_size;
    }
    out
}

/// Every task of `frame`, in progressive order: pass k covers samples
/// [k * samples_per_task, (k + 1) * samples_per_task) of every tile.
pub fn frame_tasks(settings: &RenderSettings, frame: i64) -> Vec<TaskSpec> {
    let tiles = tiles(settings.width, settings.height, settings.tile_size);
    let mut tasks = Vec::new();
    let mut start = 0;
    while start < settings.spp {
        let end = (start + settings.samples_per_task).min(settings.spp);
        for &rect in &tiles {
            tasks.push(TaskSpec { frame, rect, samples: SampleRange { start, end } });
        }
        start = end;
    }
    tasks
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_cover_the_image_once() {
        let (w, h) = (70, 45);
        let mut covered = vec![0u8; (w * h) as usize];
        for t in tiles(w, h, 32) {
            for y in t.y0..t.y0 + t.height {
                for x in t.x0..t.x0 + t.width {
                    covered[(y * w + x) as usize] += 1;
                }
            }
        }
        assert!(covered.iter().all(|&c| c == 1));
    }

    #[test]
    fn tasks_cover_every_sample_once_in_progressive_order() {
        let settings = RenderSettings {
            width: 40,
            height: 40,
            spp: 100,
            samples_per_task: 32,
            tile_size: 32,
            ..Default::default()
        };
        let tasks = frame_tasks(&settings, 0);
        assert_eq!(tasks.len(), 4 * 4);
        assert!(tasks[..4].iter().all(|t| t.samples == SampleRange { start: 0, end: 32 }));
        assert_eq!(tasks.last().unwrap().samples, SampleRange { start: 96, end: 100 });
    }
}
