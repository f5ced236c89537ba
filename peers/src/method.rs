//! One name per peer method, for `--method NAME` and the study: which input each needs, the
//! sample count its paper uses, and a call with the default parameters.

use crate::inputs::{GBufferView, Image, SampleView};
use crate::{
    guertin, mcguire, munkberg, shirley, shirley_layered_defocus, vaidyanathan, GuertinParams,
    McGuireParams, MunkbergParams, PeerError, ShirleyParams, ShirleyVariant, VaidyanathanParams,
};

/// What a method reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InputKind {
    /// A pinhole G-buffer with motion vectors (motion blur only).
    GBuffer,
    /// Stochastic samples with lens, time, motion and signed CoC.
    Samples,
}

/// A method's input.
#[derive(Debug, Clone, Copy)]
pub enum PeerInput<'a> {
    /// For [`InputKind::GBuffer`] methods.
    GBuffer(GBufferView<'a>),
    /// For [`InputKind::Samples`] methods.
    Samples(SampleView<'a>),
}

/// The peer methods by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PeerMethod {
    /// `mcguire`: McGuire et al. 2012.
    McGuire,
    /// `guertin`: Guertin et al. 2014.
    Guertin,
    /// `shirley`: Shirley et al. 2011, two scales (Appendix A).
    Shirley,
    /// `shirley4`: Shirley et al. 2011, four scales (Appendix B).
    Shirley4,
    /// `shirley-layered`: the defocus-only layered shortcut, four scales.
    ShirleyLayered,
    /// `vaidyanathan`: Vaidyanathan et al. 2015.
    Vaidyanathan,
    /// `munkberg`: Munkberg et al. 2014, 32-pixel window.
    Munkberg,
    /// `munkberg44`: Munkberg et al. 2014, 44-pixel window.
    Munkberg44,
}

impl PeerMethod {
    /// Every method, in a stable order.
    pub const ALL: [PeerMethod; 8] = [
        PeerMethod::McGuire,
        PeerMethod::Guertin,
        PeerMethod::Shirley,
        PeerMethod::Shirley4,
        PeerMethod::ShirleyLayered,
        PeerMethod::Vaidyanathan,
        PeerMethod::Munkberg,
        PeerMethod::Munkberg44,
    ];

    /// The name used on the command line.
    pub fn name(self) -> &'static str {
        match self {
            PeerMethod::McGuire => "mcguire",
            PeerMethod::Guertin => "guertin",
            PeerMethod::Shirley => "shirley",
            PeerMethod::Shirley4 => "shirley4",
            PeerMethod::ShirleyLayered => "shirley-layered",
            PeerMethod::Vaidyanathan => "vaidyanathan",
            PeerMethod::Munkberg => "munkberg",
            PeerMethod::Munkberg44 => "munkberg44",
        }
    }

    /// The method with this command-line name.
    pub fn from_name(name: &str) -> Option<PeerMethod> {
        PeerMethod::ALL.into_iter().find(|m| m.name() == name)
    }

    /// What the method reads.
    pub fn input_kind(self) -> InputKind {
        match self {
            PeerMethod::McGuire | PeerMethod::Guertin => InputKind::GBuffer,
            _ => InputKind::Samples,
        }
    }

    /// Samples per pixel the method's paper uses (None for G-buffer methods): 16 for
    /// Shirley, 8 for Vaidyanathan, 4 for Munkberg (4 to 8 in the paper).
    pub fn paper_spp(self) -> Option<usize> {
        match self {
            PeerMethod::McGuire | PeerMethod::Guertin => None,
            PeerMethod::Shirley | PeerMethod::Shirley4 | PeerMethod::ShirleyLayered => Some(16),
            PeerMethod::Vaidyanathan => Some(8),
            PeerMethod::Munkberg | PeerMethod::Munkberg44 => Some(4),
        }
    }

    /// Whether the method reproduces motion blur (false: defocus only).
    pub fn handles_motion(self) -> bool {
        !matches!(self, PeerMethod::Vaidyanathan | PeerMethod::ShirleyLayered)
    }

    /// Whether the method reproduces depth of field (false: motion blur only).
    pub fn handles_defocus(self) -> bool {
        !matches!(self, PeerMethod::McGuire | PeerMethod::Guertin)
    }

    /// Runs the method with its default parameters.
    pub fn run(self, input: &PeerInput) -> Result<Image, PeerError> {
        match (self, input) {
            (PeerMethod::McGuire, PeerInput::GBuffer(g)) => mcguire(g, &McGuireParams::default()),
            (PeerMethod::Guertin, PeerInput::GBuffer(g)) => guertin(g, &GuertinParams::default()),
            (PeerMethod::Shirley, PeerInput::Samples(s)) => shirley(s, &ShirleyParams::default()),
            (PeerMethod::Shirley4, PeerInput::Samples(s)) => shirley(
                s,
                &ShirleyParams {
                    variant: ShirleyVariant::FourScale,
                    ..Default::default()
                },
            ),
            (PeerMethod::ShirleyLayered, PeerInput::Samples(s)) => shirley_layered_defocus(
                s,
                &ShirleyParams {
                    variant: ShirleyVariant::FourScale,
                    smooth_motion: false,
                },
            ),
            (PeerMethod::Vaidyanathan, PeerInput::Samples(s)) => {
                vaidyanathan(s, &VaidyanathanParams::default())
            }
            (PeerMethod::Munkberg, PeerInput::Samples(s)) => {
                munkberg(s, &MunkbergParams::default())
            }
            (PeerMethod::Munkberg44, PeerInput::Samples(s)) => {
                munkberg(s, &MunkbergParams::window_44())
            }
            _ => Err(PeerError::Unsupported(
                "this method needs the other kind of input",
            )),
        }
    }
}
