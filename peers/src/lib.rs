//! Peer methods measured against spreadlet, on the CPU:
//!
//! - [`mcguire()`]: McGuire et al. 2012, single-velocity tile-based motion blur (G-buffer);
//! - [`guertin()`]: Guertin et al. 2014, feature-aware motion blur (G-buffer);
//! - [`shirley()`]: Shirley et al. 2011, depth-sorted sweep reconstruction (stochastic samples);
//! - [`vaidyanathan()`]: Vaidyanathan et al. 2015, layered light field reconstruction, defocus;
//! - [`munkberg()`]: Munkberg et al. 2014, layered reconstruction, defocus and motion blur.
//!
//! Every method is `fn(input, &Params) -> Result<Vec<[f32; 4]>, PeerError>`, deterministic and
//! parallel over rows or tiles (rayon). Where a paper leaves a detail open, the choice is
//! written beside the code and in `docs/PEERS.md`, and is a parameter where it is a number.

mod error;
pub mod guertin;
pub mod halton;
pub mod inputs;
pub mod layered;
pub mod mcguire;
pub mod method;
pub mod munkberg;
pub mod shirley;
mod tiles;
pub mod vaidyanathan;

pub use error::PeerError;
pub use guertin::{guertin, GuertinParams, SampleSplit};
pub use inputs::{GBufferView, Image, LensModel, Sample, SampleView, MAX_SIDE};
pub use layered::{FilterCase, LayerFilter, LayerReport, Partitions};
pub use mcguire::{mcguire, DepthCompare, McGuireParams};
pub use method::{InputKind, PeerInput, PeerMethod};
pub use munkberg::{munkberg, munkberg_with_report, MunkbergParams};
pub use shirley::{shirley, shirley_layered_defocus, ShirleyParams, ShirleyVariant, TwoScaleBlend};
pub use vaidyanathan::{vaidyanathan, vaidyanathan_with_report, VaidyanathanParams};
