//! The displacement atlas: one square tile of `R × R` texels per patch,
//! surrounded by a gutter, tiles laid out row-major in a near-square grid,
//! written as a single-channel float OpenEXR image.
//!
//! Texel `(i, j)` of a tile holds the sample at grid point `(i, j)` of its
//! patch, so texel *centres* sit exactly on the samples and the per-corner
//! UVs point at the centres of the four corner texels: bilinear filtering
//! between the corner UVs reproduces the samples, and the value at a shared
//! edge is the same number in both tiles. The gutter repeats the tile's
//! border texels outwards (clamp), so bilinear and the first mip levels do
//! not bleed a neighbour tile into a patch.
//!
//! Orientation: EXR rows run top to bottom; texture coordinates follow the
//! OBJ / USD convention with `v = 0` at the bottom row, i.e.
//! `v = 1 - (row + 0.5) / height`.

use std::io::Cursor;
use std::path::Path;

use crate::error::{Error, Result};
use crate::DVec2;

use super::Displacement;

/// Gutter width in texels: 2 covers bilinear filtering (1 texel) at the
/// full resolution and at the first mip level.
pub const DEFAULT_GUTTER: usize = 2;

/// Layout of the atlas.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Atlas {
    /// Texels per patch side (the grid resolution R).
    pub res: usize,
    pub gutter: usize,
    /// Tiles per atlas row.
    pub columns: usize,
    pub rows: usize,
    pub width: usize,
    pub height: usize,
}

impl Atlas {
    /// A near-square layout for `patches` tiles of `res` texels.
    pub fn new(patches: usize, res: usize, gutter: usize) -> Result<Atlas> {
        if patches == 0 || res < 2 {
            return Err(Error::InvalidArgument(format!(
                "atlas: {patches} patches of {res} texels; need at least one patch of 2 texels"
            )));
        }
        let columns = (patches as f64).sqrt().ceil() as usize;
        let rows = patches.div_ceil(columns);
        let tile = res + 2 * gutter;
        let (width, height) = (columns * tile, rows * tile);
        // EXR stores sizes as i32; keep well inside.
        if width > 1 << 16 || height > 1 << 16 {
            return Err(Error::InvalidArgument(format!(
                "atlas: {width} × {height} texels is too large; lower the displacement resolution"
            )));
        }
        Ok(Atlas {
            res,
            gutter,
            columns,
            rows,
            width,
            height,
        })
    }

    fn tile_origin(&self, patch: usize) -> (usize, usize) {
        let tile = self.res + 2 * self.gutter;
        (
            (patch % self.columns) * tile + self.gutter,
            (patch / self.columns) * tile + self.gutter,
        )
    }

    /// UV of the centre of texel `(i, j)` of patch `patch`.
    pub fn uv(&self, patch: usize, i: usize, j: usize) -> DVec2 {
        let (x0, y0) = self.tile_origin(patch);
        DVec2::new(
            (x0 + i) as f64 + 0.5,
            self.height as f64 - ((y0 + j) as f64 + 0.5),
        ) / DVec2::new(self.width as f64, self.height as f64)
    }

    /// The UVs of the four corners of `patch`, in the face's corner order
    /// (`(u, v)` = (0,0), (1,0), (1,1), (0,1)).
    pub fn corner_uvs(&self, patch: usize) -> [DVec2; 4] {
        let r1 = self.res - 1;
        [
            self.uv(patch, 0, 0),
            self.uv(patch, r1, 0),
            self.uv(patch, r1, r1),
            self.uv(patch, 0, r1),
        ]
    }

    /// The texels (row-major, top row first) of the displacement, gutters
    /// filled by clamping to the tile border, unused tiles 0.
    pub fn bake(&self, d: &Displacement) -> Result<Vec<f32>> {
        if d.grid.res() != self.res {
            return Err(Error::InvalidArgument(format!(
                "atlas: resolution {} does not match the displacement's {}",
                self.res,
                d.grid.res()
            )));
        }
        let mut img = vec![0.0f32; self.width * self.height];
        let g = self.gutter as isize;
        let r1 = self.res as isize - 1;
        for f in 0..d.grid.num_patches() {
            let (x0, y0) = self.tile_origin(f);
            for y in -g..=r1 + g {
                for x in -g..=r1 + g {
                    let (i, j) = (x.clamp(0, r1) as usize, y.clamp(0, r1) as usize);
                    let s = d.grid.sample(f, i, j) as usize;
                    let px = (x0 as isize + x) as usize;
                    let py = (y0 as isize + y) as usize;
                    img[py * self.width + px] = d.offsets[s] as f32;
                }
            }
        }
        Ok(img)
    }

    /// Encodes texels from [`Atlas::bake`] as a single-channel (`Y`, the
    /// OpenEXR name of a luminance-only image) 32-bit float EXR with
    /// lossless ZIP compression. Deterministic bytes: sequential encoding,
    /// increasing line order.
    pub fn encode_exr(&self, texels: &[f32]) -> Result<Vec<u8>> {
        use exr::prelude::{
            AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer, LayerAttributes,
            SmallVec, WritableImage,
        };
        if texels.len() != self.width * self.height {
            return Err(Error::InvalidArgument(format!(
                "atlas: {} texels for {} × {}",
                texels.len(),
                self.width,
                self.height
            )));
        }
        let channels = AnyChannels::sort(SmallVec::from_vec(vec![AnyChannel::new(
            "Y",
            FlatSamples::F32(texels.to_vec()),
        )]));
        let layer = Layer::new(
            (self.width, self.height),
            LayerAttributes::named("displacement"),
            Encoding::SMALL_LOSSLESS,
            channels,
        );
        let image = Image::from_layer(layer);
        let mut buf = Cursor::new(Vec::new());
        image
            .write()
            .non_parallel()
            .to_buffered(&mut buf)
            .map_err(|e| Error::backend("exr", e.to_string()))?;
        Ok(buf.into_inner())
    }
}

/// Reads a single-channel float EXR back as `(width, height, texels)`
/// (row-major, top row first): for tests and tools.
pub fn read_exr(path: &Path) -> Result<(usize, usize, Vec<f32>)> {
    let img = exr::prelude::read_first_flat_layer_from_file(path)
        .map_err(|e| Error::backend("exr", format!("{}: {e}", path.display())))?;
    let layer = img.layer_data;
    let size = layer.size;
    let ch = layer
        .channel_data
        .list
        .first()
        .ok_or_else(|| Error::parse(path, "layer", "no channel"))?;
    let texels: Vec<f32> = ch.sample_data.values_as_f32().collect();
    Ok((size.0, size.1, texels))
}
