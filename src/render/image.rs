//! An 8-bit RGB raster, its PNG encoding (the `png` crate) and the atomic
//! write of a picture, plus base64 for embedding PNGs in `report.html`.

use std::path::Path;

use crate::error::{Error, Result};
use crate::io::write_atomically;

/// An 8-bit sRGB colour.
pub type Rgb = [u8; 3];

/// A row-major RGB8 image, `(0, 0)` at the top left.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<Rgb>,
}

impl Image {
    pub fn new(width: usize, height: usize, fill: Rgb) -> Image {
        Image {
            width,
            height,
            pixels: vec![fill; width * height],
        }
    }

    #[inline]
    pub fn get(&self, x: usize, y: usize) -> Rgb {
        self.pixels[y * self.width + x]
    }

    #[inline]
    pub fn set(&mut self, x: usize, y: usize, c: Rgb) {
        self.pixels[y * self.width + x] = c;
    }

    /// Fills the rectangle `[x, x + w) × [y, y + h)`, clipped to the image.
    pub fn fill_rect(&mut self, x: i64, y: i64, w: i64, h: i64, c: Rgb) {
        let x0 = x.clamp(0, self.width as i64) as usize;
        let x1 = (x + w).clamp(0, self.width as i64) as usize;
        let y0 = y.clamp(0, self.height as i64) as usize;
        let y1 = (y + h).clamp(0, self.height as i64) as usize;
        for yy in y0..y1 {
            self.pixels[yy * self.width + x0..yy * self.width + x1].fill(c);
        }
    }

    /// Copies `src` with its top-left corner at `(x, y)`, clipped.
    pub fn blit(&mut self, src: &Image, x: usize, y: usize) {
        for sy in 0..src.height {
            let ty = y + sy;
            if ty >= self.height {
                break;
            }
            let n = src.width.min(self.width.saturating_sub(x));
            let d = ty * self.width + x;
            self.pixels[d..d + n].copy_from_slice(&src.pixels[sy * src.width..sy * src.width + n]);
        }
    }

    /// Alpha-blends `c` over pixel `(x, y)` (ignored outside the image).
    pub fn blend(&mut self, x: i64, y: i64, c: Rgb, alpha: f64) {
        if x < 0 || y < 0 || x >= self.width as i64 || y >= self.height as i64 {
            return;
        }
        let p = &mut self.pixels[y as usize * self.width + x as usize];
        let a = alpha.clamp(0.0, 1.0);
        for k in 0..3 {
            p[k] = (p[k] as f64 * (1.0 - a) + c[k] as f64 * a).round() as u8;
        }
    }

    /// PNG bytes (8-bit RGB, default compression).
    pub fn encode_png(&self) -> Result<Vec<u8>> {
        // The size is checked below and the sink is a Vec: an encoder error
        // left is a bug.
        let bad = |e: png::EncodingError| Error::internal(format!("PNG encoding: {e}"));
        if self.width == 0 || self.height == 0 || self.width > u32::MAX as usize {
            return Err(Error::InvalidArgument(format!(
                "PNG encoding: image size {}x{} is empty or too large",
                self.width, self.height
            )));
        }
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.width as u32, self.height as u32);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            let mut w = enc.write_header().map_err(bad)?;
            w.write_image_data(self.pixels.as_flattened())
                .map_err(bad)?;
            w.finish().map_err(bad)?;
        }
        Ok(out)
    }

    /// Writes the image as PNG to `path` atomically (a temporary file
    /// renamed into place: a reader never sees half a picture, an error
    /// leaves `path` as it was).
    pub fn write_png(&self, path: &Path) -> Result<()> {
        let bytes = self.encode_png()?;
        write_atomically(path, |w| {
            w.write_all(&bytes).map_err(|e| Error::io(path, e))
        })
    }
}

/// Decodes an 8-bit RGB or RGBA PNG (alpha dropped); for tests and checks.
pub fn decode_png(bytes: &[u8]) -> Result<Image> {
    let bad = |e: png::DecodingError| Error::parse("<png>", "data", format!("PNG decoding: {e}"));
    let mut dec = png::Decoder::new(bytes);
    dec.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = dec.read_info().map_err(bad)?;
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).map_err(bad)?;
    let (w, h) = (info.width as usize, info.height as usize);
    let ch = match info.color_type {
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Indexed => {
            return Err(Error::parse("<png>", "data", "indexed PNG after expansion"))
        }
    };
    let pixels = buf[..w * h * ch]
        .chunks_exact(ch)
        .map(|p| match ch {
            1 | 2 => [p[0]; 3],
            _ => [p[0], p[1], p[2]],
        })
        .collect();
    Ok(Image {
        width: w,
        height: h,
        pixels,
    })
}

/// Standard base64 (RFC 4648, with padding), for `data:` URIs.
pub fn base64(bytes: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16
            | (c.get(1).copied().unwrap_or(0) as u32) << 8
            | c.get(2).copied().unwrap_or(0) as u32;
        out.push(T[(n >> 18) as usize & 63] as char);
        out.push(T[(n >> 12) as usize & 63] as char);
        out.push(if c.len() > 1 {
            T[(n >> 6) as usize & 63] as char
        } else {
            '='
        });
        out.push(if c.len() > 2 {
            T[n as usize & 63] as char
        } else {
            '='
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc4648_vectors() {
        for (i, o) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(i.as_bytes()), o);
        }
    }

    #[test]
    fn png_round_trip() {
        let mut img = Image::new(7, 5, [10, 20, 30]);
        img.set(3, 2, [255, 0, 128]);
        let back = decode_png(&img.encode_png().unwrap()).unwrap();
        assert_eq!(back, img);
    }
}
