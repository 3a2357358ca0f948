//! The integrators, peers over one shared path layer: the path tracer (`path`, and the same
//! estimator on 8 or 16 lanes, `wavefront`), bidirectional path tracing (`bdpt`) and stochastic
//! progressive photon mapping (`sppm`, which builds on `bdpt`'s subpaths). `shared` holds the
//! path logic they all call (MIS and the delta convention, light sampling and the radiance a
//! light sample carries, roulette, the shading frame), each piece once.
//! `render_task` (in the module above) is the one place that dispatches on the integrator.

pub mod bdpt;
pub mod path;
pub mod shared;
pub mod sppm;
pub mod wavefront;

pub use shared::Stats;
