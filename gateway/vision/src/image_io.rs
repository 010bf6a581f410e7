//! Reading and writing frames as PNG files (8- or 16-bit greyscale).

use protocol::{MonoImage, Pixels};
use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum ImageFileError {
    #[error("{path}: cannot open: {cause}")]
    Open { path: String, cause: std::io::Error },
    #[error("{path}: not a readable image: {message}")]
    Decode { path: String, message: String },
    #[error("{path}: the image is {found}; the localizer needs 8- or 16-bit greyscale (convert colour frames to luminance first)")]
    NotGreyscale { path: String, found: String },
    #[error("{path}: cannot write: {message}")]
    Write { path: String, message: String },
}

pub fn load_png(path: &Path) -> Result<MonoImage, ImageFileError> {
    let p = path.display().to_string();
    let reader = image::ImageReader::open(path)
        .map_err(|cause| ImageFileError::Open {
            path: p.clone(),
            cause,
        })?
        .with_guessed_format()
        .map_err(|cause| ImageFileError::Open {
            path: p.clone(),
            cause,
        })?;
    let img = reader.decode().map_err(|e| ImageFileError::Decode {
        path: p.clone(),
        message: e.to_string(),
    })?;
    let (w, h) = (img.width(), img.height());
    let pixels = match img {
        image::DynamicImage::ImageLuma8(b) => Pixels::Mono8(b.into_raw()),
        image::DynamicImage::ImageLuma16(b) => Pixels::Mono16(b.into_raw()),
        other => {
            return Err(ImageFileError::NotGreyscale {
                path: p,
                found: format!("{:?}", other.color()),
            })
        }
    };
    MonoImage::new(w, h, pixels).map_err(|e| ImageFileError::Decode {
        path: p,
        message: e.to_string(),
    })
}

pub fn save_png(img: &MonoImage, path: &Path) -> Result<(), ImageFileError> {
    let p = path.display().to_string();
    let err = |e: image::ImageError| ImageFileError::Write {
        path: p.clone(),
        message: e.to_string(),
    };
    match &img.pixels {
        Pixels::Mono8(d) => image::GrayImage::from_raw(img.width, img.height, d.clone())
            .expect("MonoImage sizes are checked")
            .save(path)
            .map_err(err),
        Pixels::Mono16(d) => image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(
            img.width,
            img.height,
            d.clone(),
        )
        .expect("MonoImage sizes are checked")
        .save(path)
        .map_err(err),
    }
}
