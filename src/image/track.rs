//! Stable grain ids over a sequence of frames: each track predicts its next
//! position (constant velocity), detections are matched to predictions
//! greedily by distance within a gate, unmatched detections start new tracks
//! (grains entering) and tracks unmatched for too long end (grains leaving).

use super::detect::Disk;
use crate::error::{Error, Result};

#[derive(Debug, Clone)]
pub struct TrackOptions {
    /// Largest distance [px] between a prediction and its detection.
    pub max_jump_px: f64,
    /// Largest relative change of radius between matched detections.
    pub max_radius_change: f64,
    /// Frames a lost track is remembered (a missed detection, an occlusion).
    pub memory: usize,
}

impl TrackOptions {
    /// Defaults for disks of at least `radius_min` px: a gate of one radius,
    /// which no neighbour's centre can come within.
    pub fn new(radius_min: f64) -> Self {
        TrackOptions {
            max_jump_px: radius_min,
            max_radius_change: 0.2,
            memory: 2,
        }
    }
}

struct Track {
    id: u64,
    position: [f64; 2],
    velocity: [f64; 2],
    radius: f64,
    last_frame: usize,
}

/// Assigns ids frame by frame (online, so a long sequence needs no memory of
/// its images).
pub struct Tracker {
    options: TrackOptions,
    tracks: Vec<Track>,
    next_id: u64,
    frame: usize,
}

impl Tracker {
    pub fn new(options: TrackOptions) -> Result<Self> {
        if !(options.max_jump_px.is_finite() && options.max_jump_px > 0.0) {
            return Err(Error::Invalid(format!(
                "the tracking gate must be a positive number of pixels, not {}",
                options.max_jump_px
            )));
        }
        Ok(Tracker {
            options,
            tracks: Vec::new(),
            next_id: 0,
            frame: 0,
        })
    }

    /// Ids for the disks of the next frame. The first frame's disks get 0, 1,
    /// … in their order; each new grain gets the next unused number, so an id
    /// is never reused.
    pub fn assign(&mut self, disks: &[Disk]) -> Vec<u64> {
        let f = self.frame;
        self.frame += 1;
        let memory = self.options.memory;
        self.tracks.retain(|t| f - t.last_frame <= memory + 1);
        let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
        for (t, track) in self.tracks.iter().enumerate() {
            let dt = (f - track.last_frame) as f64;
            let predicted = [
                track.position[0] + dt * track.velocity[0],
                track.position[1] + dt * track.velocity[1],
            ];
            for (k, d) in disks.iter().enumerate() {
                let dist = ((d.x - predicted[0]).powi(2) + (d.y - predicted[1]).powi(2)).sqrt();
                let radius_change = (d.r - track.radius).abs() / track.radius;
                if dist <= self.options.max_jump_px
                    && radius_change <= self.options.max_radius_change
                {
                    pairs.push((dist, t, k));
                }
            }
        }
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut ids: Vec<Option<u64>> = vec![None; disks.len()];
        let mut track_taken = vec![false; self.tracks.len()];
        for (_, t, k) in pairs {
            if track_taken[t] || ids[k].is_some() {
                continue;
            }
            track_taken[t] = true;
            let track = &mut self.tracks[t];
            let d = &disks[k];
            let dt = (f - track.last_frame) as f64;
            track.velocity = [
                (d.x - track.position[0]) / dt,
                (d.y - track.position[1]) / dt,
            ];
            track.position = [d.x, d.y];
            track.radius = d.r;
            track.last_frame = f;
            ids[k] = Some(track.id);
        }
        ids.into_iter()
            .zip(disks)
            .map(|(id, d)| {
                id.unwrap_or_else(|| {
                    let id = self.next_id;
                    self.next_id += 1;
                    self.tracks.push(Track {
                        id,
                        position: [d.x, d.y],
                        velocity: [0.0, 0.0],
                        radius: d.r,
                        last_frame: f,
                    });
                    id
                })
            })
            .collect()
    }
}

/// Ids for every disk of every frame: `ids[f][k]` belongs to `frames[f][k]`.
pub fn track_sequence(frames: &[Vec<Disk>], options: &TrackOptions) -> Result<Vec<Vec<u64>>> {
    let mut tracker = Tracker::new(options.clone())?;
    Ok(frames.iter().map(|disks| tracker.assign(disks)).collect())
}
