//! Pictures as PNG files.

use std::io::Write;
use std::path::Path;

use super::Image;
use crate::Result;

impl Image {
    /// True when every pixel is opaque.
    fn is_opaque(&self) -> bool {
        self.rgba.chunks_exact(4).all(|p| p[3] == 255)
    }

    /// Encodes the image as PNG, 8 bits per channel: RGB when every pixel is opaque, RGBA
    /// otherwise.
    ///
    /// # Errors
    /// When writing to `out` fails.
    pub fn encode_png(&self, out: &mut dyn Write) -> std::io::Result<()> {
        let mut encoder = png::Encoder::new(out, self.width, self.height);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_compression(png::Compression::Fast);
        let rgb: Vec<u8>;
        let data = if self.is_opaque() {
            encoder.set_color(png::ColorType::Rgb);
            rgb = self
                .rgba
                .chunks_exact(4)
                .flat_map(|p| [p[0], p[1], p[2]])
                .collect();
            &rgb
        } else {
            encoder.set_color(png::ColorType::Rgba);
            &self.rgba
        };
        let mut writer = encoder.write_header().map_err(std::io::Error::other)?;
        writer
            .write_image_data(data)
            .map_err(std::io::Error::other)?;
        writer.finish().map_err(std::io::Error::other)
    }

    /// Writes the image as a PNG file (see [`Image::encode_png`]), whatever the extension.
    /// The file appears only when complete (temporary file in the same folder, then
    /// rename), as [`crate::io::write_mesh`] writes meshes.
    ///
    /// # Errors
    /// [`crate::Error::Output`] if the path is a directory or its directory is missing or
    /// not writable; [`crate::Error::Io`] if a write fails.
    pub fn write_png(&self, path: &Path) -> Result<()> {
        crate::io::write_atomically(path, |w| self.encode_png(w))
    }
}
