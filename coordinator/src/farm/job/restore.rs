//! Rebuilding a job from the database after a restart: each tile's merged prefix and pending
//! results, then the frames' adaptive stopping scales.

use common::film::{ErrorEstimate, TileAccum};

use super::{Job, TaskState};

impl Job {
    /// Restores a tile from the database: tasks `0..prefix` summed in `sums`, and the pending
    /// results. Call [`Job::restore_adaptive`] once every tile is restored.
    pub fn restore_tile(
        &mut self,
        frame: u32,
        tile: u32,
        prefix: u32,
        sums: Option<TileAccum>,
        pending: Vec<(u32, TileAccum)>,
    ) -> Result<(), String> {
        let t = self
            .frames
            .get_mut(frame as usize)
            .and_then(|f| f.tiles.get_mut(tile as usize))
            .ok_or_else(|| format!("stored tile {frame}/{tile} is not in the job"))?;
        let count = |a: &TileAccum| a.pixels.iter().map(|p| p.n as u64).sum::<u64>();
        let sums = sums.unwrap_or(TileAccum { rect: t.sums.rect, pixels: Vec::new(), rejected: 0 });
        if prefix as usize > t.tasks.len() || sums.rect != t.sums.rect {
            return Err(format!("stored tile {frame}/{tile} does not fit the job"));
        }
        for k in 0..prefix {
            t.tasks[k as usize] = TaskState::Merged;
        }
        let mut restored = count(&sums);
        t.sums = sums;
        t.prefix = prefix;
        for (k, acc) in pending {
            if k < prefix || k as usize >= t.tasks.len() {
                continue; // already in the sums (a crash between the two writes cannot happen,
                          // they share a transaction, but an old row must never count twice)
            }
            t.tasks[k as usize] = TaskState::Merged;
            restored += count(&acc);
            t.pending.insert(k, acc);
        }
        t.merged = prefix + t.pending.len() as u32;
        t.rel_mse = ErrorEstimate::of_pixels(&t.sums.pixels).rel_mse;
        // Pixel samples count the camera's, as `merge` counts them.
        if t.light {
            self.light_samples_done += restored;
            return Ok(());
        }
        self.samples_done += restored;
        self.frames[frame as usize].samples_done += restored;
        Ok(())
    }

    /// Restores the frames' stopping scales and bidirectional frames' pilot images (as stored:
    /// they were fixed from the pilot alone, which the merged sums no longer show; `pilots` by
    /// frame index) and the tiles they stop.
    pub fn restore_adaptive(
        &mut self,
        scales: &[Option<f64>],
        pilots: Vec<(u32, Vec<[f32; 3]>)>,
    ) -> Result<(), String> {
        for (frame, &scale) in self.frames.iter_mut().zip(scales) {
            frame.scale = scale;
        }
        let pixels = self.settings.width as usize * self.settings.height as usize;
        for (f, pilot) in pilots {
            let frame =
                self.frames.get_mut(f as usize).filter(|_| pilot.len() == pixels).ok_or_else(
                    || format!("the stored pilot image of frame {f} does not fit the job"),
                )?;
            frame.pilot = Some(pilot);
        }
        // A bidirectional frame's tiles' errors are shares of the image's.
        if self.light_tile().is_some() {
            let (width, height) = (self.settings.width, self.settings.height);
            for frame in &mut self.frames {
                frame.update_all_rel_mse(width, height);
            }
        }
        let light = self.light_tile().is_some();
        if let Some(f) =
            self.frames.iter().position(|f| light && f.scale.is_some() && f.pilot.is_none())
        {
            return Err(format!("frame {f} has an adaptive scale but no stored pilot image"));
        }
        for f in 0..self.frames.len() {
            self.update_adaptive(f);
        }
        Ok(())
    }

    /// The pilot images of bidirectional frames under adaptive sampling, for the database.
    pub fn pilot(&self, frame: u32) -> Option<&[[f32; 3]]> {
        self.frames.get(frame as usize).and_then(|f| f.pilot.as_deref())
    }

    /// The frames' stopping scales, for the database.
    pub fn scales(&self) -> Vec<Option<f64>> {
        self.frames.iter().map(|f| f.scale).collect()
    }
}
