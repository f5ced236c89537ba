//! Host of the integration stage (`pyramid.wgsl` through [`super::pyramid`]): the GPU twin of
//! [`crate::pipeline::integrate`]. The convolution pyramid runs on the GPU; the exact
//! integrator is the lattice Green's function by FFT on the CPU, as `poisson::ExactIntegrator`,
//! its result uploaded into the pyramid's output pass.

use poisson::pyramid::PAD;
use poisson::{ExactIntegrator, Plane};
use rayon::prelude::*;

use super::frame::FrameBuffers;
use super::synth::GpuSynthesizer;
use super::GpuError;
use crate::pipeline::integrate::Integrator;
use crate::pipeline::types::FrameParams;

impl GpuSynthesizer {
    /// Encodes the integration of one chunk's Laplacian planes. For [`Integrator::Exact`] the
    /// splat must have finished (its planes are read back first).
    pub(super) fn encode_integrate(
        &self,
        enc: &mut wgpu::CommandEncoder,
        fb: &FrameBuffers,
        frame: &FrameParams,
        integrator: Integrator,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) -> Result<(), GpuError> {
        if integrator == Integrator::Pyramid {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("integrate"),
                timestamp_writes: timestamps,
            });
            fb.pyramid.encode(&self.pyramid, &mut pass, false);
            return Ok(());
        }
        // Read the Laplacian back, integrate, upload into synthesis level 0, run the output
        // pass with scale 1.
        let (pw, ph) = (frame.padded_width as usize, frame.padded_height as usize);
        let lap = fb.pyramid.analysis_sets[0];
        let padded = fb
            .pyramid
            .read_level(&self.ctx, &fb.pyramid.analysis, lap)?;
        let exact = ExactIntegrator::new(pw, ph);
        let primal: Vec<Plane> = padded
            .par_iter()
            .map(|p| {
                let lap = p.crop(PAD as isize, PAD as isize, pw, ph);
                if lap.data.iter().all(|&v| v == 0.0) {
                    Plane::new(pw, ph)
                } else {
                    exact.integrate(&lap)
                }
            })
            .collect();
        let refs: Vec<&Plane> = primal.iter().collect();
        fb.pyramid.upload_padded(
            &self.ctx,
            &fb.pyramid.synthesis,
            fb.pyramid.synthesis_sets[0],
            &refs,
        );
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("integrate"),
            timestamp_writes: None,
        });
        fb.pyramid.encode(&self.pyramid, &mut pass, true);
        Ok(())
    }
}
