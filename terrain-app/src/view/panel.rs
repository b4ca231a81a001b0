//! The viewer's on-screen panel (egui): the method, one quality slider, wireframe, LOD-level
//! colouring, freeze selection, vertical exaggeration and the sun; live figures (fps, CPU and
//! GPU frame ms, triangles, patches, the error bound the method promises, the measured p99 on
//! demand, streaming figures for stores). The panel only reads the viewer's state and returns
//! [`Action`]s, which go through the same path as keys and scripts.

use terrain_app::methods::LodMethod;

use super::script::Toggle;
use super::{Action, Stats, UiState};

/// What the panel shows of the viewer's state this frame.
#[derive(Debug, Clone)]
pub(crate) struct PanelView {
    pub kind: LodMethod,
    pub store: bool,
    /// The slider's error target, pixels (`None`: the method's own parameter was given).
    pub error_px: Option<f64>,
    /// The method's own parameter as set: name and value.
    pub own: (&'static str, f64),
    /// Whether the quality is a screen-space error bound in pixels.
    pub pixels: bool,
    pub sun: (f64, f64),
    pub busy: bool,
    /// Keyframes recorded so far, when recording.
    pub recording: Option<usize>,
    pub adapter: String,
    pub orbit: bool,
    pub speed: f64,
}

/// The LOD colours' legend: grid cells per triangle edge, finest first (terrain-gpu's
/// palette, the colours the renderer draws).
fn lod_legend(ui: &mut egui::Ui, kind: LodMethod) {
    use terrain_gpu::render::{LOD_NO_PATCH, LOD_PALETTE};
    let swatch = |ui: &mut egui::Ui, c: [f32; 3], text: &str| {
        ui.horizontal(|ui| {
            let [r, g, b] = c.map(|v| (v * 255.0).round() as u8);
            let (rect, _) = ui.allocate_exact_size(egui::vec2(14.0, 10.0), egui::Sense::hover());
            ui.painter().rect_filled(rect, 0.0, egui::Color32::from_rgb(r, g, b));
            ui.label(text);
        });
    };
    ui.label(if kind == LodMethod::Geomorph {
        "cells per triangle edge (2^level):"
    } else {
        "cells per triangle edge:"
    });
    ui.horizontal_wrapped(|ui| {
        for (c, name) in LOD_PALETTE {
            swatch(ui, c, name);
        }
        if terrain_app::method::registry::draws_mesh(kind) {
            swatch(ui, LOD_NO_PATCH, "a mesh, no patches");
        }
    });
}

/// Draws the panel and pushes what the user changed to `actions`.
pub(crate) fn ui(
    ctx: &egui::Context,
    view: &PanelView,
    state: &UiState,
    stats: &Stats,
    actions: &mut Vec<Action>,
) {
    egui::Window::new("terrain view").default_pos([8.0, 8.0]).resizable(false).show(ctx, |ui| {
        ui.label(&view.adapter);
        let mut kind = view.kind;
        egui::ComboBox::from_label("method").selected_text(kind.name()).show_ui(ui, |ui| {
            for &m in LodMethod::ALL.iter() {
                if m == LodMethod::OutOfCore && !view.store {
                    continue;
                }
                ui.selectable_value(&mut kind, m, m.name());
            }
        });
        if kind != view.kind {
            actions.push(Action::Method(kind));
        }
        if view.busy {
            ui.label("preparing ...");
        }
        // The one quality slider: the error target in pixels, mapped onto the method's own
        // parameter (shown beside it) by the registry, as `--error-px` is.
        let mut q = view.error_px.unwrap_or(super::ERROR_PX_DEFAULT);
        let (lo, hi) = super::ERROR_PX_RANGE;
        ui.horizontal(|ui| {
            let slider = egui::Slider::new(&mut q, lo..=hi)
                .logarithmic(true)
                .suffix(" px")
                .text("error target");
            let r = ui.add(slider);
            if r.drag_stopped() || (r.changed() && !r.dragged()) {
                actions.push(Action::Quality(q));
            }
            let (name, value) = view.own;
            ui.label(match view.error_px {
                Some(_) => format!("-> {name} = {value:.4}"),
                None => format!("({name} = {value:.4} from --method-param)"),
            });
        });
        let mut toggle = |ui: &mut egui::Ui, t: Toggle, on: bool, label: &str| {
            let mut v = on;
            if ui.checkbox(&mut v, label).changed() {
                actions.push(Action::Set(t, v));
            }
        };
        toggle(ui, Toggle::Wireframe, state.wireframe, "wireframe");
        toggle(ui, Toggle::ColourLevels, state.colour_levels, "LOD colours (L)");
        if state.colour_levels {
            lod_legend(ui, view.kind);
        }
        toggle(ui, Toggle::Freeze, state.freeze, "freeze selection (F)");
        let mut ex = state.exaggeration;
        if ui
            .add(egui::Slider::new(&mut ex, 0.25..=10.0).logarithmic(true).text("exaggeration"))
            .drag_stopped()
        {
            actions.push(Action::Exaggeration(ex));
        }
        let (mut az, mut el) = view.sun;
        let a = ui.add(egui::Slider::new(&mut az, 0.0..=360.0).text("sun azimuth"));
        let e = ui.add(egui::Slider::new(&mut el, 1.0..=90.0).text("sun elevation"));
        if a.changed() || e.changed() {
            actions.push(Action::Sun(az, el));
        }
        ui.separator();
        let fps = if stats.frame_s > 0.0 { 1.0 / stats.frame_s } else { 0.0 };
        ui.label(format!("{fps:.1} fps, viewer frame {:.1} ms", stats.viewer_ms));
        ui.label(format!("engine frame {:.1} ms, CPU {:.1} ms", stats.engine_ms, stats.cpu_ms));
        ui.label(format!("GPU {}", stats.gpu));
        ui.label(format!("{} triangles, {} patches", stats.triangles, stats.patches));
        let (name, value) = view.own;
        ui.label(if view.pixels {
            format!("error bound: {name} = {value:.3} px (screen space)")
        } else {
            format!("error bound: none in pixels ({name} = {value:.3}); measure it")
        });
        ui.horizontal(|ui| {
            if ui.button("measure p99 (M)").clicked() {
                actions.push(Action::Measure);
            }
            ui.label(state.measured_p99.as_deref().unwrap_or("-"));
        });
        if let Some(s) = &stats.stream {
            ui.label(format!(
                "stream: resident {:.1} / {:.0} MiB, late {:.2} MiB ({} blocks), queued {:.2} \
                 MiB ({} requests)",
                s.resident_mib,
                s.budget_mib,
                s.late_mib,
                s.late_blocks,
                s.queued_mib,
                s.queue_depth
            ));
        }
        ui.separator();
        ui.label(format!(
            "{} mode (O), speed {:.0} m/s (wheel); drag to look, WASD QE move",
            if view.orbit { "orbit" } else { "fly" },
            view.speed
        ));
        let rec = match view.recording {
            Some(n) => format!("recording: {n} keyframes (R stops)"),
            None => "R records a flight".into(),
        };
        ui.label(rec);
        if let Some(m) = &state.message {
            ui.label(m);
        }
    });
}
