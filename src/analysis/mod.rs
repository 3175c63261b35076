//! Analysis of the input mesh M (Fitmaps §3.1): the Fitmap and what it is
//! built from.
//!
//! - [`fitmap`]: S-fitmap and M-fitmap, exact and fast ([`compute_fitmap`]);
//! - [`neighbourhood`]: the balls `B(p, r)` and the coarse proxies of M;
//! - [`cubic`]: the local frame and the least-squares cubic height function;
//! - [`normals`]: triangle areas, area-weighted vertex normals;
//! - [`compare`]: agreement of two Fitmaps (Spearman ρ, radius steps).

pub mod compare;
pub mod cubic;
pub mod fitmap;
pub mod neighbourhood;
pub mod normals;

pub use compare::{compare_fitmaps, spearman, FitmapAgreement};
pub use fitmap::{
    compute_fitmap, compute_fitmap_cancellable, compute_fitmap_with_progress, exact_flip_fractions,
    fitmap_radii, Fitmap, FitmapOptions, FitmapStats,
};
