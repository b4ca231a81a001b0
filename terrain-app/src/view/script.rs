//! Scripted input for `terrain view --script FILE`: what a person would do, one command per
//! line, so tests and demos drive the viewer without one. Blank lines and `#` comments are
//! skipped. Commands run in order at the start of a frame until a `wait`, a `screenshot` (taken
//! of that frame) or the end; a script frame advances the camera by a fixed 1/60 s whatever the
//! wall time, so a script gives the same poses on every machine.
//!
//! ```text
//! key down W        # hold a key: W A S D Q E (move), shift (4x speed)
//! key up W          # release it
//! mouse 40 -10      # a drag of (dx, dy) pixels: mouse look (orbit: turn around the centre)
//! wheel 2           # wheel steps: faster (fly) or closer (orbit)
//! orbit             # toggle fly / orbit (the O key)
//! method dss-1      # switch method; the script waits until it is ready
//! quality 3         # the quality slider: an error target in pixels (as --error-px)
//! wireframe on      # on | off; also: freeze on|off, colour-levels on|off, panel on|off
//! exaggeration 2    # vertical exaggeration
//! camera 1,2,3,90,-30   # set the pose (as --camera)
//! record            # start / stop recording the flight (the R key)
//! measure           # measure this frame's p99 px (the M key); the script waits for it
//! screenshot out.png    # read this frame back from the window's surface into a PNG
//! wait 10           # draw 10 frames
//! quit              # close the window (workers joined) and exit 0
//! ```

use std::path::PathBuf;

use anyhow::{Context, bail};

use terrain_app::methods::LodMethod;

/// A key the viewer reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Key {
    /// Forward (orbit: closer).
    W,
    /// Left.
    A,
    /// Back.
    S,
    /// Right.
    D,
    /// Down.
    Q,
    /// Up.
    E,
    /// Four times the speed.
    Shift,
}

impl Key {
    pub(crate) fn parse(s: &str) -> Option<Self> {
        Some(match s.to_ascii_lowercase().as_str() {
            "w" => Key::W,
            "a" => Key::A,
            "s" => Key::S,
            "d" => Key::D,
            "q" => Key::Q,
            "e" => Key::E,
            "shift" => Key::Shift,
            _ => return None,
        })
    }
}

/// A switch of the panel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Toggle {
    /// Wireframe.
    Wireframe,
    /// Freeze the selection.
    Freeze,
    /// Colour by LOD level.
    ColourLevels,
    /// Show the panel.
    Panel,
}

/// One scripted action.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Command {
    /// Key pressed (`true`) or released.
    Key(Key, bool),
    /// Mouse drag, pixels.
    Mouse(f64, f64),
    /// Wheel steps.
    Wheel(f64),
    /// Fly / orbit.
    Orbit,
    /// Switch the method.
    Method(LodMethod),
    /// The quality slider: an error target in pixels, mapped onto the method's own parameter.
    Quality(f64),
    /// A panel switch.
    Set(Toggle, bool),
    /// Vertical exaggeration.
    Exaggeration(f64),
    /// The pose, as `--camera` spells it.
    Camera(String),
    /// Start / stop recording.
    Record,
    /// Measure the frame (the M key); the script waits for the result.
    Measure,
    /// Read this frame back into a PNG.
    Screenshot(PathBuf),
    /// Draw this many frames.
    Wait(u32),
    /// Draw frames until `--flight` has played to its end.
    WaitFlight,
    /// Close and exit.
    Quit,
}

/// Parses a script (see the module docs); errors name the line.
pub(crate) fn parse(text: &str) -> anyhow::Result<Vec<Command>> {
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let cmd = parse_line(line).with_context(|| format!("script line {}: `{line}`", n + 1))?;
        out.push(cmd);
    }
    Ok(out)
}

fn parse_line(line: &str) -> anyhow::Result<Command> {
    let words: Vec<&str> = line.split_whitespace().collect();
    let num = |s: &str| -> anyhow::Result<f64> {
        let v: f64 = s.parse().with_context(|| format!("`{s}` is not a number"))?;
        if !v.is_finite() {
            bail!("`{s}` is not a finite number");
        }
        Ok(v)
    };
    let on_off = |s: &str| -> anyhow::Result<bool> {
        match s {
            "on" | "true" | "1" => Ok(true),
            "off" | "false" | "0" => Ok(false),
            _ => bail!("expected on or off, got `{s}`"),
        }
    };
    let toggle = |name: &str| match name {
        "wireframe" => Some(Toggle::Wireframe),
        "freeze" => Some(Toggle::Freeze),
        "colour-levels" | "color-levels" => Some(Toggle::ColourLevels),
        "panel" => Some(Toggle::Panel),
        _ => None,
    };
    Ok(match words[..] {
        ["key", dir @ ("down" | "up"), k] => {
            let key = Key::parse(k).with_context(|| format!("unknown key `{k}`"))?;
            Command::Key(key, dir == "down")
        }
        ["mouse", dx, dy] => Command::Mouse(num(dx)?, num(dy)?),
        ["wheel", n] => Command::Wheel(num(n)?),
        ["orbit"] => Command::Orbit,
        ["method", m] => Command::Method(
            <LodMethod as clap::ValueEnum>::from_str(m, true)
                .map_err(|e| anyhow::anyhow!("unknown method `{m}`: {e}"))?,
        ),
        ["quality", v] => Command::Quality(num(v)?),
        [name, v] if toggle(name).is_some() => Command::Set(toggle(name).unwrap(), on_off(v)?),
        ["exaggeration", v] => {
            let v = num(v)?;
            if v <= 0.0 {
                bail!("exaggeration must be positive");
            }
            Command::Exaggeration(v)
        }
        ["camera", spec] => {
            terrain_app::camera::parse(spec, None)?;
            Command::Camera(spec.to_string())
        }
        ["record"] => Command::Record,
        ["measure"] => Command::Measure,
        ["screenshot", path] => Command::Screenshot(PathBuf::from(path)),
        ["wait", n] => Command::Wait(n.parse().with_context(|| format!("`{n}` frames?"))?),
        ["wait-flight"] => Command::WaitFlight,
        ["quit"] => Command::Quit,
        _ => bail!("unknown command (see `terrain view --help` for the script format)"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_command_parses() {
        let s = "# a test\nkey down W\nkey up shift\nmouse 40 -10.5\nwheel -2\norbit\n\
                 method dss-1\nquality 8\nwireframe on\nfreeze off\npanel off\n\
                 exaggeration 2\ncamera 1,2,3,90,-30\nrecord\nmeasure\nscreenshot a b.png\n\nwait 10 # x\nquit\n";
        let err = parse(s).unwrap_err().to_string();
        assert!(err.contains("line 16"), "{err}");
        let s = s.replace("screenshot a b.png", "screenshot out.png");
        let c = parse(&s).unwrap();
        assert_eq!(
            c,
            vec![
                Command::Key(Key::W, true),
                Command::Key(Key::Shift, false),
                Command::Mouse(40.0, -10.5),
                Command::Wheel(-2.0),
                Command::Orbit,
                Command::Method(LodMethod::Dss1),
                Command::Quality(8.0),
                Command::Set(Toggle::Wireframe, true),
                Command::Set(Toggle::Freeze, false),
                Command::Set(Toggle::Panel, false),
                Command::Exaggeration(2.0),
                Command::Camera("1,2,3,90,-30".into()),
                Command::Record,
                Command::Measure,
                Command::Screenshot("out.png".into()),
                Command::Wait(10),
                Command::Quit,
            ]
        );
    }

    #[test]
    fn bad_lines_are_refused_with_their_number() {
        for (bad, what) in [
            ("key down X", "unknown key"),
            ("mouse 1", "unknown command"),
            ("method nope", "unknown method"),
            ("quality NaN", "finite"),
            ("wireframe maybe", "on or off"),
            ("camera 1,2,3", "--camera"),
            ("wait -1", "frames"),
        ] {
            let e = format!("{:#}", parse(&format!("wait 1\n{bad}")).unwrap_err());
            assert!(e.contains("line 2") && e.contains(what), "{bad}: {e}");
        }
    }
}
