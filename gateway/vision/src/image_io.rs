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

/// The largest image file read (a 64 MP 16-bit frame is 128 MB raw; PNG compresses).
pub const MAX_IMAGE_BYTES: u64 = 256 << 20;

pub fn load_png(path: &Path) -> Result<MonoImage, ImageFileError> {
    let p = path.display().to_string();
    // Through the bounded reader: a FIFO is refused before it is opened (never a
    // hang), a device such as /dev/zero is not read without end.
    let open = |cause| ImageFileError::Open {
        path: p.clone(),
        cause,
    };
    let bytes = protocol::config::read_bytes_bounded(path, MAX_IMAGE_BYTES, "an image file")
        .map_err(open)?;
    decode_png(&bytes, &p)
}

/// A PNG file's bytes as a frame (`name` names it in messages): 8- or 16-bit greyscale.
pub fn decode_png(bytes: &[u8], name: &str) -> Result<MonoImage, ImageFileError> {
    let p = name.to_string();
    let open = |cause| ImageFileError::Open {
        path: p.clone(),
        cause,
    };
    let reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(open)?;
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

#[cfg(test)]
mod bounded_tests {
    use super::*;

    /// A FIFO or a device is refused before it is opened: the call returns at once.
    #[test]
    fn a_fifo_and_a_device_are_refused_without_blocking() {
        let dir = std::env::temp_dir().join(format!("vision-fifo-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let fifo = dir.join("frame.png");
        let _ = std::fs::remove_file(&fifo);
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(made.success());
        for path in [fifo.as_path(), Path::new("/dev/zero")] {
            let e = load_png(path).unwrap_err().to_string();
            assert!(e.contains("not a regular file"), "{e}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
