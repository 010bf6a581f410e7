//! Monochrome camera frames: the one image type shared by cameras, the renderer and the
//! localizer. Integer pixel coordinates are pixel centres; the image centre is
//! ((W-1)/2, (H-1)/2).

/// Pixel storage. 16-bit frames keep the camera's full range (Mono16 / PNG 16-bit).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Pixels {
    Mono8(Vec<u8>),
    Mono16(Vec<u16>),
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MonoImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Pixels,
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("image buffer holds {got} pixels but {width}x{height} needs {want}")]
pub struct SizeMismatch {
    pub width: u32,
    pub height: u32,
    pub want: usize,
    pub got: usize,
}

impl MonoImage {
    pub fn new(width: u32, height: u32, pixels: Pixels) -> Result<Self, SizeMismatch> {
        let want = width as usize * height as usize;
        let got = match &pixels {
            Pixels::Mono8(p) => p.len(),
            Pixels::Mono16(p) => p.len(),
        };
        if want != got {
            return Err(SizeMismatch {
                width,
                height,
                want,
                got,
            });
        }
        Ok(Self {
            width,
            height,
            pixels,
        })
    }

    pub fn bit_depth(&self) -> u8 {
        match self.pixels {
            Pixels::Mono8(_) => 8,
            Pixels::Mono16(_) => 16,
        }
    }

    /// The largest value a pixel can hold (255 or 65535).
    pub fn max_value(&self) -> u32 {
        match self.pixels {
            Pixels::Mono8(_) => u8::MAX as u32,
            Pixels::Mono16(_) => u16::MAX as u32,
        }
    }

    /// Pixel value at (x, y); panics outside the frame (callers index inside bounds).
    #[inline]
    pub fn get(&self, x: u32, y: u32) -> u32 {
        let i = y as usize * self.width as usize + x as usize;
        match &self.pixels {
            Pixels::Mono8(p) => p[i] as u32,
            Pixels::Mono16(p) => p[i] as u32,
        }
    }

    /// The image centre in pixel coordinates (pixel centres are integers).
    pub fn centre(&self) -> [f64; 2] {
        [
            (self.width as f64 - 1.0) / 2.0,
            (self.height as f64 - 1.0) / 2.0,
        ]
    }
}
