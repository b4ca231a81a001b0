//! Recording a flight in the viewer (the CDLOD demo's camera recorder): the R key starts
//! recording camera keyframes, one every [`KEY_INTERVAL_S`] of the viewer's clock (a script
//! frame is 1/60 s), and stops and writes them in the `flights/` JSON format (world positions,
//! yaw and pitch, `height_above` unused), which `terrain_core::flight::FlightSpec::parse`
//! validates before the file is written; `--flight` plays one back.

use std::path::Path;

use anyhow::{Context, bail};
use glam::DVec3;
use terrain_core::flight::FlightSpec;

/// Seconds between recorded keyframes (the flight's Catmull-Rom spline fills the frames
/// between them on playback).
pub(crate) const KEY_INTERVAL_S: f64 = 0.5;

/// A flight being recorded.
#[derive(Debug, Clone, Default)]
pub(crate) struct Recorder {
    /// `(t, position, yaw, pitch)` per keyframe.
    keys: Vec<(f64, DVec3, f64, f64)>,
    /// Clock since the recording started, seconds.
    clock: f64,
}

impl Recorder {
    /// Advances the clock by `dt` and records the pose when a keyframe is due (always the first).
    pub(crate) fn tick(&mut self, dt: f64, position: DVec3, yaw: f64, pitch: f64) {
        let due = self.keys.last().is_none_or(|k| self.clock - k.0 >= KEY_INTERVAL_S - 1e-9);
        if due {
            self.keys.push((self.clock, position, yaw, pitch));
        }
        self.clock += dt;
    }

    /// Keyframes so far.
    pub(crate) fn len(&self) -> usize {
        self.keys.len()
    }

    /// The flight as `flights/` JSON, named `name`, played at `fps`; validated by the flight
    /// reader. Refused with fewer than two keyframes.
    pub(crate) fn to_json(&self, name: &str, fps: f64, fov_deg: f64) -> anyhow::Result<String> {
        if self.keys.len() < 2 {
            bail!(
                "a flight needs at least two keyframes ({} recorded: record for at least {} s)",
                self.keys.len(),
                KEY_INTERVAL_S
            );
        }
        let keyframes: Vec<_> = self
            .keys
            .iter()
            .map(|(t, p, yaw, pitch)| {
                serde_json::json!({ "t": t, "position": [p.x, p.y, p.z], "yaw": yaw, "pitch": pitch })
            })
            .collect();
        let json = serde_json::to_string_pretty(&serde_json::json!({
            "name": name,
            "fps": fps,
            "fov_y_deg": fov_deg,
            "keyframes": keyframes,
        }))?;
        FlightSpec::parse(&json).context("the recorded flight does not read back")?;
        Ok(json)
    }

    /// Writes the flight to `path` (see [`Recorder::to_json`]).
    pub(crate) fn save(&self, path: &Path, fps: f64, fov_deg: f64) -> anyhow::Result<()> {
        let name = path.file_stem().and_then(|s| s.to_str()).unwrap_or("recorded");
        let json = self.to_json(name, fps, fov_deg)?;
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("could not create {}", dir.display()))?;
        }
        std::fs::write(path, json).with_context(|| format!("could not write {}", path.display()))
    }
}

#[cfg(test)]
mod tests {
    use terrain_core::flight::{KeyPosition, KeyView};

    use super::*;

    #[test]
    fn a_recording_reads_back_as_the_poses_it_recorded() {
        let mut r = Recorder::default();
        for k in 0..90 {
            let p = DVec3::new(f64::from(k), 2.0 * f64::from(k), 100.0);
            r.tick(1.0 / 60.0, p, f64::from(k), -10.0);
        }
        // 1.5 s at 60 frames: keys at 0, 0.5, 1.0.
        assert_eq!(r.len(), 3);
        let spec = FlightSpec::parse(&r.to_json("t", 30.0, 60.0).unwrap()).unwrap();
        assert_eq!(spec.keyframes.len(), 3);
        let k = spec.keyframes[1];
        assert!((k.t - 0.5).abs() < 1e-9, "{}", k.t);
        assert_eq!(k.position, KeyPosition::World(DVec3::new(30.0, 60.0, 100.0)));
        assert_eq!(k.view, KeyView::YawPitch { yaw: 30.0, pitch: -10.0 });
    }

    #[test]
    fn one_keyframe_is_not_a_flight() {
        let mut r = Recorder::default();
        r.tick(0.1, DVec3::ZERO, 0.0, 0.0);
        assert!(r.to_json("t", 30.0, 60.0).unwrap_err().to_string().contains("two keyframes"));
    }
}
