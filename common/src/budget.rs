//! What loading one scene may cost: bytes a bundle inflates to, decoded texels, triangles after
//! instancing. Each is checked before the work it bounds (a zip entry while it inflates, an image
//! from its header, a placement before its triangles are copied), so that a small hostile file
//! is refused for the cost of reading its headers. The coordinator sets the budgets
//! (`--max-scene-mib`, `--max-megatexels`, `--max-megatriangles` on `coordinator serve` and
//! `render`) and hands them to its workers when they join, so that a scene the coordinator
//! accepted is one every worker can load.

use serde::{Deserialize, Serialize};

use crate::gltf::SceneError;

/// The budgets of one scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default)]
pub struct SceneBudget {
    /// Bytes a `.zip` bundle may inflate to, over all its files; and, counted apart, bytes the
    /// compressed buffer views of its glTF (`EXT_meshopt_compression`) may decode to.
    pub inflated_bytes: u64,
    /// Files a `.zip` bundle may hold.
    pub entries: u64,
    /// Decoded texels over all images (4 bytes each as RGBA8).
    pub texels: u64,
    /// Triangles over all placements of all meshes.
    pub triangles: u64,
}

impl Default for SceneBudget {
    fn default() -> Self {
        SceneBudget {
            inflated_bytes: 2 << 30,
            entries: 10_000,
            texels: 256_000_000,
            triangles: 32_000_000,
        }
    }
}

/// One line of the budget, for messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Line {
    /// [`SceneBudget::inflated_bytes`].
    InflatedBytes,
    /// [`SceneBudget::entries`].
    Entries,
    /// [`SceneBudget::texels`].
    Texels,
    /// [`SceneBudget::triangles`].
    Triangles,
}

impl Line {
    /// What is counted, and the setting that sets its budget.
    fn describe(self) -> (&'static str, &'static str) {
        match self {
            Line::InflatedBytes => {
                ("bytes unpacked", "--max-scene-mib on coordinator serve and render")
            }
            Line::Entries => ("files in the archive", "a fixed limit"),
            Line::Texels => ("decoded texels", "--max-megatexels on coordinator serve and render"),
            Line::Triangles => (
                "triangles after instancing",
                "--max-megatriangles on coordinator serve and render",
            ),
        }
    }
}

/// The error for a scene that needs at least `needed` of `line` against a budget of `budget`;
/// `at` names where the count went over.
pub fn over_budget(line: Line, needed: u64, budget: u64, at: &str) -> SceneError {
    let (what, setting) = line.describe();
    SceneError(format!(
        "the scene needs at least {} {what} ({at}), over this farm's budget of {} ({setting})",
        amount(needed),
        amount(budget)
    ))
}

/// `1234567` as `1.23 M`, small numbers as they are.
fn amount(n: u64) -> String {
    match n {
        0..10_000 => n.to_string(),
        10_000..1_000_000 => format!("{:.1} k", n as f64 / 1e3),
        1_000_000..1_000_000_000 => format!("{:.1} M", n as f64 / 1e6),
        _ => format!("{:.2} G", n as f64 / 1e9),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refusal_names_the_figure_the_budget_and_its_setting() {
        let e = over_budget(Line::Texels, 335_544_320, 268_435_456, "image 3, 8192x8192").0;
        assert_eq!(
            e,
            "the scene needs at least 335.5 M decoded texels (image 3, 8192x8192), over this farm's budget of 268.4 M (--max-megatexels on coordinator serve and render)"
        );
        assert_eq!(amount(9_999), "9999");
        assert_eq!(amount(12_345), "12.3 k");
        assert_eq!(amount(2_000_000), "2.0 M");
        assert_eq!(amount(4_300_000_000), "4.30 G");
    }

    #[test]
    fn a_missing_key_takes_its_default() {
        let b: SceneBudget = serde_json::from_str(r#"{"texels": 5}"#).unwrap();
        assert_eq!(b, SceneBudget { texels: 5, ..SceneBudget::default() });
    }
}
