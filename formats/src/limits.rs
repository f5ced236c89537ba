//! The size limits of every reader, in one place: what a file or a camera may ask the program
//! to allocate, whatever it claims. Each bound is checked before anything large is allocated.

/// Largest image edge a camera may ask for, pixels.
pub const MAX_IMAGE_EDGE: u32 = 32_768;

/// Largest G-buffer (width x height, with its overscan): 8192 x 8192 pixels, twice an 8K frame.
pub const MAX_PIXELS: usize = 8192 * 8192;

/// Largest number of samples a G-buffer file may declare (pixels x channels, over all its
/// parts): 16 channels of the largest image, 4 GiB of f32.
pub const MAX_SAMPLES: usize = 16 * MAX_PIXELS;

/// Largest number of samples a deep OpenEXR may hold, over all its pixels: 2^26 (64 per pixel
/// of a 1024 x 1024 frame), 2 GiB as the reader holds them.
pub const MAX_DEEP_SAMPLES: usize = 1 << 26;

/// Largest number of samples per channel of any other EXR file (stochastic frames hold
/// `height x spp` rows): 2^28, 1 GiB of f32.
pub const MAX_CHANNEL_SAMPLES: usize = 1 << 28;
