//! Splitting a frame into tiles (the farm's jobs cut each tile's samples into tasks).

use common::film::Rect;

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
}
