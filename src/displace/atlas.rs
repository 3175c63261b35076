//! The displacement atlas: one square tile of `R × R` texels per patch,
//! surrounded by a gutter, tiles laid out row-major in a grid, written as
//! OpenEXR images of two maps on the same layout ([`AtlasMap`]): the
//! scalar offsets (`displacement*.exr`, one channel) and the displacement
//! vectors (`displacement_vector*.exr`, RGB = xyz in object space). Hosts
//! that displace along their own tessellation's normals (Blender) are off
//! by up to 1.5 % of the diagonal with the scalar map where the limit
//! surface folds or meets a crease (spot, bunny, fandisk: the sample
//! directions turn by tens of degrees within a texel there); with the
//! vector map they land on `displaced.ply`. One image holding every patch
//! ([`AtlasLayout::Single`], `displacement.exr`), or UDIM tiles of
//! [`UDIM_PATCHES`]² patches each ([`AtlasLayout::Udim`],
//! `displacement.1001.exr`, `displacement.1002.exr`, …; tile `k` covers
//! UV square `[k mod 10, k mod 10 + 1) × [⌊k/10⌋, ⌊k/10⌋ + 1)`, the UDIM
//! convention, so UVs run past 1).
//!
//! Texel `(i, j)` of a tile holds the sample at grid point `(i, j)` of its
//! patch, so texel *centres* sit exactly on the samples and the per-corner
//! UVs point at the centres of the four corner texels: bilinear filtering
//! between the corner UVs reproduces the samples, and the value at a shared
//! edge is the same number in both tiles. The gutter repeats the tile's
//! border texels outwards (clamp).
//!
//! Mip-mapping: a level-`L` texel averages a `2^L`-texel block of the full
//! image, and a bilinear lookup at level `L` reads two level-`L` texels per
//! axis. Tiles start on multiples of `2^L` texels ([`MIP_LEVELS`]: the tile
//! pitch is rounded up to a multiple of `2^MIP_LEVELS`) and the gutter is at
//! least `2^(L−1)` texels on every side, so no lookup inside a patch's UV
//! square at levels `0..=MIP_LEVELS` reads a texel of another patch's
//! tile: the blocks it touches hold the patch's own texels and its clamped
//! border only. With [`DEFAULT_GUTTER`] = 4 that holds up to level 3
//! (1/8 resolution, e.g. a `.tx` made by `maketx`); beyond it, bleeding
//! starts.
//!
//! **Tiles of different sizes** (a grid of per-patch resolutions,
//! [`Atlas::for_grid`]): each tile's pitch box (its texels plus the
//! gutter, rounded up to a multiple of `2^MIP_LEVELS`) is placed by shelf
//! packing, largest first (ties by patch index, so the layout is
//! deterministic): shelves as tall as their first tile, filled left to
//! right, stacked top to bottom, a new UDIM image when the next shelf no
//! longer fits. Every box starts on a multiple of `2^MIP_LEVELS` texels
//! and keeps its gutter, so the mip-map promise above holds per tile. The
//! per-corner UVs point at each tile's corner texels as before, so hosts
//! (USD, the Blender add-on) read the atlas unchanged.
//!
//! Orientation: EXR rows run top to bottom; texture coordinates follow the
//! OBJ / USD convention with `v = 0` at the bottom row, i.e.
//! `v = 1 - (row + 0.5) / height` (plus the UDIM tile's offset).

use std::io::Cursor;
use std::path::Path;

use crate::error::{Error, Result};
use crate::DVec2;

use super::Displacement;

/// Gutter width in texels on each side of a tile: with tiles aligned to
/// `2^MIP_LEVELS` texels, `2^(MIP_LEVELS−1)` = 4 keeps mip levels up to
/// [`MIP_LEVELS`] free of bleeding (module docs).
pub const DEFAULT_GUTTER: usize = 4;

/// The deepest mip level the default layout serves without bleeding
/// (module docs): tile pitch a multiple of `2^MIP_LEVELS` = 8 texels.
pub const MIP_LEVELS: u32 = 3;

/// Patches per UDIM tile side: a UDIM tile holds up to 8 × 8 patches
/// (at R = 64 and the default gutter, 640 × 640 texels).
pub const UDIM_PATCHES: usize = 8;

/// One image for every patch, or UDIM tiles.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum AtlasLayout {
    #[default]
    Single,
    Udim,
}

/// Texel storage of the EXR files.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum TexelType {
    /// 32-bit float: the offsets exactly as computed (to f32).
    #[default]
    Float,
    /// 16-bit half float: 11 significant bits, relative error ≤ 2^-11 of
    /// each offset (offsets are small, so absolute error is far below the
    /// fit's).
    Half,
}

/// Where one patch's tile lies.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
struct Tile {
    image: usize,
    /// The texel of the patch's grid point (0, 0).
    x0: usize,
    y0: usize,
    /// Texels per side, and the side of its pitch box.
    res: usize,
    pitch: usize,
}

/// Layout of the atlas.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Atlas {
    /// Texels per patch side (the grid resolution R; the largest tile's
    /// with tiles of different sizes).
    pub res: usize,
    /// Gutter on the left and top of each tile (the right and bottom
    /// ones are at least as wide: see `pitch`).
    pub gutter: usize,
    /// Tile pitch in texels: `res + 2·gutter` rounded up to a multiple of
    /// `2^MIP_LEVELS` when `gutter` is the default (module docs).
    pub pitch: usize,
    /// Tiles per image row and rows per image.
    pub columns: usize,
    pub rows: usize,
    /// Size of one image (of every UDIM tile).
    pub width: usize,
    pub height: usize,
    /// Number of images (1 unless UDIM).
    pub images: usize,
    pub layout: AtlasLayout,
    /// Per patch, its tile.
    tiles: Vec<Tile>,
}

impl Atlas {
    /// A near-square single-image layout for `patches` tiles of `res`
    /// texels.
    pub fn new(patches: usize, res: usize, gutter: usize) -> Result<Atlas> {
        Atlas::with_layout(patches, res, gutter, AtlasLayout::Single)
    }

    /// The layout of the outputs: `layout`, [`DEFAULT_GUTTER`].
    pub fn for_outputs(patches: usize, res: usize, layout: AtlasLayout) -> Result<Atlas> {
        Atlas::with_layout(patches, res, DEFAULT_GUTTER, layout)
    }

    /// `patches` tiles of `res` texels in `layout`. The pitch is aligned
    /// to `2^MIP_LEVELS` texels whenever the gutter is at least the
    /// default, so that the mip-map promise of the module docs holds.
    pub fn with_layout(
        patches: usize,
        res: usize,
        gutter: usize,
        layout: AtlasLayout,
    ) -> Result<Atlas> {
        if patches == 0 || res < 2 {
            return Err(Error::InvalidArgument(format!(
                "atlas: {patches} patches of {res} texels; need at least one patch of 2 texels"
            )));
        }
        let align = if gutter >= DEFAULT_GUTTER {
            1usize << MIP_LEVELS
        } else {
            1
        };
        let pitch = (res + 2 * gutter).div_ceil(align) * align;
        let (columns, rows, images) = match layout {
            AtlasLayout::Single => {
                let columns = (patches as f64).sqrt().ceil() as usize;
                (columns, patches.div_ceil(columns), 1)
            }
            AtlasLayout::Udim => {
                let per = UDIM_PATCHES.min((patches as f64).sqrt().ceil() as usize);
                let images = patches.div_ceil(per * per);
                // UDIM numbers run 1001..=1999: 10 tiles per row, 100 rows.
                if images > 1000 {
                    return Err(Error::option(
                        "atlas",
                        format!("atlas: {patches} patches need {images} UDIM tiles (max 1000)"),
                    ));
                }
                (per, per, images)
            }
        };
        let (width, height) = (columns * pitch, rows * pitch);
        check_size(width, height)?;
        let per_image = columns * rows;
        let tiles = (0..patches)
            .map(|patch| {
                let (image, k) = (patch / per_image, patch % per_image);
                Tile {
                    image,
                    x0: (k % columns) * pitch + gutter,
                    y0: (k / columns) * pitch + gutter,
                    res,
                    pitch,
                }
            })
            .collect();
        Ok(Atlas {
            res,
            gutter,
            pitch,
            columns,
            rows,
            width,
            height,
            images,
            layout,
            tiles,
        })
    }

    /// The layout of the outputs for `grid`: [`Atlas::for_outputs`] when
    /// it is uniform, else tiles of each patch's resolution, shelf-packed
    /// (module docs), [`DEFAULT_GUTTER`].
    pub fn for_grid(grid: &super::PatchGrid, layout: AtlasLayout) -> Result<Atlas> {
        if grid.is_uniform() {
            return Atlas::for_outputs(grid.num_patches(), grid.res(), layout);
        }
        let res: Vec<usize> = (0..grid.num_patches()).map(|f| grid.patch_res(f)).collect();
        Atlas::packed(&res, DEFAULT_GUTTER, layout)
    }

    /// Tiles of `res[f]` texels per patch, shelf-packed (module docs).
    /// `columns` and `rows` are those of the largest tile's pitch that the
    /// image would hold.
    pub fn packed(res: &[usize], gutter: usize, layout: AtlasLayout) -> Result<Atlas> {
        if res.is_empty() || res.iter().any(|&r| r < 2) {
            return Err(Error::InvalidArgument(
                "atlas: need at least one patch, each of at least 2 texels".into(),
            ));
        }
        let align = if gutter >= DEFAULT_GUTTER {
            1usize << MIP_LEVELS
        } else {
            1
        };
        let pitch_of = |r: usize| (r + 2 * gutter).div_ceil(align) * align;
        let mut order: Vec<usize> = (0..res.len()).collect();
        order.sort_by(|&a, &b| res[b].cmp(&res[a]).then(a.cmp(&b)));
        let max_pitch = pitch_of(res[order[0]]);
        let area: f64 = res
            .iter()
            .map(|&r| (pitch_of(r) * pitch_of(r)) as f64)
            .sum();
        // A near-square image (or UDIM tile, at most UDIM_PATCHES of the
        // largest tiles per side), in whole alignment blocks.
        let mut side = (area.sqrt().ceil() as usize).div_ceil(align) * align;
        if layout == AtlasLayout::Udim {
            side = side.min(UDIM_PATCHES * max_pitch);
        }
        let width = side.max(max_pitch);
        let mut tiles = vec![
            Tile {
                image: 0,
                x0: 0,
                y0: 0,
                res: 0,
                pitch: 0
            };
            res.len()
        ];
        let (mut image, mut x, mut y, mut shelf) = (0, 0, 0, 0);
        let mut height = 0;
        for &f in &order {
            let p = pitch_of(res[f]);
            if x + p > width {
                (x, y) = (0, y + shelf);
                shelf = 0;
            }
            if layout == AtlasLayout::Udim && shelf == 0 && y + p > width {
                (image, x, y) = (image + 1, 0, 0);
            }
            shelf = shelf.max(p);
            tiles[f] = Tile {
                image,
                x0: x + gutter,
                y0: y + gutter,
                res: res[f],
                pitch: p,
            };
            x += p;
            height = height.max(y + shelf);
        }
        let height = if layout == AtlasLayout::Udim {
            width
        } else {
            height
        };
        if image >= 1000 {
            return Err(Error::option(
                "atlas",
                format!(
                    "atlas: {} patches need {} UDIM tiles (max 1000)",
                    res.len(),
                    image + 1
                ),
            ));
        }
        check_size(width, height)?;
        Ok(Atlas {
            res: res[order[0]],
            gutter,
            pitch: max_pitch,
            columns: width / max_pitch,
            rows: height / max_pitch,
            width,
            height,
            images: image + 1,
            layout,
            tiles,
        })
    }

    /// Image of `patch` and the texel of its grid point (0, 0) there.
    fn tile_origin(&self, patch: usize) -> (usize, usize, usize) {
        let t = &self.tiles[patch];
        (t.image, t.x0, t.y0)
    }

    /// Texels per side of `patch`'s tile.
    pub fn tile_res(&self, patch: usize) -> usize {
        self.tiles[patch].res
    }

    /// The UDIM number of image `k` (1001, 1002, …).
    pub fn udim(k: usize) -> usize {
        1001 + k
    }

    /// The file name of image `k`: `displacement.exr`, or
    /// `displacement.<UDIM>.exr`.
    pub fn file_name(&self, k: usize) -> String {
        self.file_name_of(AtlasMap::Scalar, k)
    }

    /// The file name of image `k` of `map`: `displacement.exr` or
    /// `displacement_vector.exr`, with `.<UDIM>` before `.exr` in UDIM
    /// layout.
    pub fn file_name_of(&self, map: AtlasMap, k: usize) -> String {
        let stem = map.stem();
        match self.layout {
            AtlasLayout::Single => format!("{stem}.exr"),
            AtlasLayout::Udim => format!("{stem}.{}.exr", Atlas::udim(k)),
        }
    }

    /// The texture path a USD or renderer reads (UDIM's `<UDIM>` token).
    pub fn texture_pattern(&self) -> &'static str {
        match self.layout {
            AtlasLayout::Single => "displacement.exr",
            AtlasLayout::Udim => "displacement.<UDIM>.exr",
        }
    }

    /// UV of the centre of texel `(i, j)` of patch `patch`.
    pub fn uv(&self, patch: usize, i: usize, j: usize) -> DVec2 {
        let (image, x0, y0) = self.tile_origin(patch);
        let local = DVec2::new(
            (x0 + i) as f64 + 0.5,
            self.height as f64 - ((y0 + j) as f64 + 0.5),
        ) / DVec2::new(self.width as f64, self.height as f64);
        match self.layout {
            AtlasLayout::Single => local,
            AtlasLayout::Udim => local + DVec2::new((image % 10) as f64, (image / 10) as f64),
        }
    }
    /// The UVs of the four corners of `patch`, in the face's corner order
    /// (`(u, v)` = (0,0), (1,0), (1,1), (0,1)).
    pub fn corner_uvs(&self, patch: usize) -> [DVec2; 4] {
        let r1 = self.tiles[patch].res - 1;
        [
            self.uv(patch, 0, 0),
            self.uv(patch, r1, 0),
            self.uv(patch, r1, r1),
            self.uv(patch, 0, r1),
        ]
    }

    /// The texels of image 0 (row-major, top row first); see
    /// [`Atlas::bake_images`].
    pub fn bake(&self, d: &Displacement) -> Result<Vec<f32>> {
        Ok(self.bake_images(d)?.swap_remove(0))
    }

    /// The texels of every image (row-major, top row first), each tile's
    /// whole pitch box filled by clamping to the tile border (so a mip
    /// block that straddles the border averages the patch's own values),
    /// unused tiles 0.
    pub fn bake_images(&self, d: &Displacement) -> Result<Vec<Vec<f32>>> {
        self.bake_images_of(d, d.reconstruction, |s| d.offsets[s])
    }

    /// [`Atlas::bake_images`] of one value per sample of `d`'s grid, laid
    /// out as samples for a bilinear lookup whatever `d`'s reconstruction
    /// (the B-spline evaluated at the samples, for USD: `super::bspline`).
    pub fn bake_sample_images(&self, d: &Displacement, values: &[f64]) -> Result<Vec<Vec<f32>>> {
        self.bake_images_of(d, super::Reconstruction::Bilinear, |s| values[s])
    }

    /// The three channels (x, y, z) of every image of the vector map: at
    /// each sample its displacement `offset · direction` (module docs).
    pub fn bake_vector_images(&self, d: &Displacement) -> Result<Vec<[Vec<f32>; 3]>> {
        let v = d.vectors();
        let component = |c: usize| self.bake_images_of(d, d.reconstruction, |s| v[s][c]);
        let (x, y, z) = (component(0)?, component(1)?, component(2)?);
        Ok(x.into_iter()
            .zip(y)
            .zip(z)
            .map(|((x, y), z)| [x, y, z])
            .collect())
    }

    /// [`Atlas::bake_images`] of `value(sample)`.
    fn bake_images_of(
        &self,
        d: &Displacement,
        reconstruction: super::Reconstruction,
        value: impl Fn(usize) -> f64,
    ) -> Result<Vec<Vec<f32>>> {
        let patches = d.grid.num_patches();
        if let Some(f) = (0..patches.min(self.tiles.len()))
            .find(|&f| d.grid.patch_res(f) != self.tiles[f].res)
            .or((patches > self.tiles.len()).then_some(self.tiles.len()))
        {
            return Err(Error::internal(format!(
                "atlas: the tile of patch {f} does not match the displacement's resolution {}",
                d.grid.patch_res(f)
            )));
        }
        let mut imgs = vec![vec![0.0f32; self.width * self.height]; self.images];
        let g = self.gutter as isize;
        // B-spline coefficients: each texel the tile's coefficient, the
        // gutter its linear phantom one texel out (what a cubic lookup at
        // the border reads; `super::bspline` module docs) and that
        // texel's value beyond.
        let tiles = (reconstruction == super::Reconstruction::Bspline)
            .then(|| super::BsplineTiles::new(&d.grid));
        let mut terms = Vec::new();
        for f in 0..patches {
            let (image, x0, y0) = self.tile_origin(f);
            let far = (self.tiles[f].pitch - self.gutter) as isize - 1;
            let r1 = self.tiles[f].res as isize - 1;
            let img = imgs
                .get_mut(image)
                .ok_or_else(|| Error::internal(format!("atlas: patch {f} beyond the layout")))?;
            for y in -g..=far {
                for x in -g..=far {
                    let v = match &tiles {
                        None => {
                            let (i, j) = (x.clamp(0, r1) as usize, y.clamp(0, r1) as usize);
                            value(d.grid.sample(f, i, j) as usize)
                        }
                        Some(t) => {
                            terms.clear();
                            let (i, j) = (x.clamp(-1, r1 + 1), y.clamp(-1, r1 + 1));
                            t.coefficient(f, i, j, 1.0, &mut terms);
                            terms.iter().map(|&(s, w)| w * value(s as usize)).sum()
                        }
                    };
                    let px = (x0 as isize + x) as usize;
                    let py = (y0 as isize + y) as usize;
                    img[py * self.width + px] = v as f32;
                }
            }
        }
        Ok(imgs)
    }

    /// Encodes texels from [`Atlas::bake`] as a single-channel (`Y`, the
    /// OpenEXR name of a luminance-only image) 32-bit float EXR with
    /// lossless ZIP compression.
    pub fn encode_exr(&self, texels: &[f32]) -> Result<Vec<u8>> {
        self.encode_exr_as(texels, TexelType::Float)
    }

    /// [`Atlas::encode_exr`] in `ty` (half floats rounded to nearest).
    /// Deterministic bytes: sequential encoding, increasing line order.
    pub fn encode_exr_as(&self, texels: &[f32], ty: TexelType) -> Result<Vec<u8>> {
        self.encode_exr_channels(AtlasMap::Scalar, &[("Y", texels)], ty)
    }

    /// The vector map's image from [`Atlas::bake_vector_images`]: channels
    /// `R`, `G`, `B` holding x, y, z (the names every reader maps to a
    /// colour, which is how DCCs read vector displacement), in `ty`.
    pub fn encode_vector_exr_as(&self, xyz: &[Vec<f32>; 3], ty: TexelType) -> Result<Vec<u8>> {
        let [x, y, z] = xyz;
        self.encode_exr_channels(AtlasMap::Vector, &[("R", x), ("G", y), ("B", z)], ty)
    }

    fn encode_exr_channels(
        &self,
        map: AtlasMap,
        channels: &[(&str, &[f32])],
        ty: TexelType,
    ) -> Result<Vec<u8>> {
        use exr::prelude::{
            f16, AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer, LayerAttributes,
            SmallVec, WritableImage,
        };
        let mut list = Vec::new();
        for (name, texels) in channels {
            if texels.len() != self.width * self.height {
                return Err(Error::InvalidArgument(format!(
                    "atlas: {} texels for {} × {}",
                    texels.len(),
                    self.width,
                    self.height
                )));
            }
            let samples = match ty {
                TexelType::Float => FlatSamples::F32(texels.to_vec()),
                TexelType::Half => {
                    FlatSamples::F16(texels.iter().map(|&t| f16::from_f32(t)).collect())
                }
            };
            list.push(AnyChannel::new(*name, samples));
        }
        let channels = AnyChannels::sort(SmallVec::from_vec(list));
        let layer = Layer::new(
            (self.width, self.height),
            LayerAttributes::named(map.stem()),
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

/// The two maps the outputs carry, on the same layout.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum AtlasMap {
    /// `displacement.exr`: the signed offset along the displacement
    /// direction (one channel, `Y`).
    Scalar,
    /// `displacement_vector.exr`: the displacement itself, `offset ·
    /// direction`, in the control mesh's object space (`R`, `G`, `B` = x,
    /// y, z), for hosts whose normals are not the limit surface's.
    Vector,
}

/// EXR stores sizes as i32; keep well inside.
fn check_size(width: usize, height: usize) -> Result<()> {
    if width > 1 << 16 || height > 1 << 16 {
        return Err(Error::option(
            "displacement_res",
            format!(
                "atlas: {width} × {height} texels is too large; lower the displacement resolution"
            ),
        ));
    }
    Ok(())
}

impl AtlasMap {
    fn stem(self) -> &'static str {
        match self {
            AtlasMap::Scalar => "displacement",
            AtlasMap::Vector => "displacement_vector",
        }
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

/// An EXR channel as read back: its name and texels.
pub type Channel = (String, Vec<f32>);

/// Reads every channel of an EXR's first layer as `(width, height,
/// [(name, texels)])`, channels in the file's (alphabetical) order: for
/// tests and tools.
pub fn read_exr_channels(path: &Path) -> Result<(usize, usize, Vec<Channel>)> {
    let img = exr::prelude::read_first_flat_layer_from_file(path)
        .map_err(|e| Error::backend("exr", format!("{}: {e}", path.display())))?;
    let layer = img.layer_data;
    let channels = layer
        .channel_data
        .list
        .iter()
        .map(|c| (c.name.to_string(), c.sample_data.values_as_f32().collect()))
        .collect();
    Ok((layer.size.0, layer.size.1, channels))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packed_tiles_of_mixed_sizes_do_not_overlap_and_stay_aligned() {
        // Sizes as the allocation makes them (2^k + 1), in a scrambled
        // order; both layouts.
        let res: Vec<usize> = (0..70).map(|k| [3, 17, 5, 33, 9, 65, 3][k % 7]).collect();
        for layout in [AtlasLayout::Single, AtlasLayout::Udim] {
            let a = Atlas::packed(&res, DEFAULT_GUTTER, layout).unwrap();
            let align = 1usize << MIP_LEVELS;
            let boxes: Vec<(usize, usize, usize, usize)> = a
                .tiles
                .iter()
                .map(|t| (t.image, t.x0 - a.gutter, t.y0 - a.gutter, t.pitch))
                .collect();
            for (f, &(img, x, y, p)) in boxes.iter().enumerate() {
                assert_eq!(a.tile_res(f), res[f]);
                // The pitch box holds the tile and its gutter on every side,
                // starts on the mip alignment and lies inside its image.
                assert!(p >= res[f] + 2 * a.gutter && p % align == 0);
                assert!(x % align == 0 && y % align == 0, "{layout:?} tile {f}");
                assert!(img < a.images && x + p <= a.width && y + p <= a.height);
                for (g, &(img2, x2, y2, p2)) in boxes.iter().enumerate().skip(f + 1) {
                    let apart =
                        img != img2 || x + p <= x2 || x2 + p2 <= x || y + p <= y2 || y2 + p2 <= y;
                    assert!(apart, "{layout:?}: tiles {f} and {g} overlap");
                }
                // Corner UVs sit on the corner texels' centres.
                let uv = a.corner_uvs(f);
                let local = uv[0] - DVec2::new((img % 10) as f64, (img / 10) as f64);
                assert!((local.x * a.width as f64 - (x + a.gutter) as f64 - 0.5).abs() < 1e-9);
            }
        }
    }
}
