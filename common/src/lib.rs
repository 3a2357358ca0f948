//! What coordinator and worker must agree on.
//!
//! # Layout
//! - [`scene`]: the scene model (plain data, f64 placements).
//! - [`gltf`]: glTF 2.0 loading and validation into a [`scene::Scene`].
//! - [`animation`]: node animation curves and world transforms at any time.
//! - [`deform`]: posing skinned and morphing meshes (linear blend skinning, morph targets).
//! - [`bundle`]: uploaded scene bundles (`.glb`, `.gltf`, `.zip`) resolved only inside themselves.
//! - [`budget`]: what loading one scene may cost (inflated bytes, texels, triangles).
//! - [`settings`]: render settings (the JSON of PRODUCT.md) with validation.
//! - [`envmap`]: equirectangular environment maps (HDR, EXR) and their direction convention.
//! - [`film`]: per-pixel partial sums that merge exactly, variance and error estimates.
//! - [`protocol`]: task specifications and results.
//! - [`error`]: the kinds of refusal in the farm protocol, and their HTTP statuses.
//! - [`spread`]: how a caller lends its threads to work that may run at once.
//!
//! No networking, no threads (a caller lends its own through [`spread::Spread`]), no rendering
//! here.

#![warn(missing_docs)]

pub mod animation;
pub mod budget;
pub mod bundle;
pub mod deform;
pub mod envmap;
pub mod error;
pub mod film;
pub mod gltf;
pub mod protocol;
pub mod scene;
pub mod settings;
pub mod spread;
