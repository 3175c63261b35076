//! `subdfit render INPUT -o PICTURE.png`: pictures of a mesh or of a
//! `convert` output folder, ray cast on the CPU (see `subdfit::render`).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Result;
use clap::{Args, ValueEnum};
use subdfit::raycast::RayBackend;
use subdfit::render::{parse_size, render, RenderOptions, View, What};

use crate::fit::progress_bars;

#[derive(Copy, Clone, ValueEnum)]
pub enum WhatArg {
    Input,
    Fitmap,
    Patches,
    Limit,
    Displaced,
    Error,
}

#[derive(Copy, Clone, ValueEnum)]
pub enum ViewArg {
    Front,
    Side,
    Top,
    Iso,
    Auto,
}

#[derive(Copy, Clone, ValueEnum)]
pub enum RaysArg {
    Embree,
    Rust,
}

#[derive(Args)]
pub struct RenderArgs {
    /// A mesh file (OBJ, PLY, OFF, STL; read as a control mesh for
    /// `patches` and `limit`) or a `subdfit convert` output folder.
    input: PathBuf,
    /// What to picture: the input; its Fitmap (F_S and F_M); the limit
    /// surface with patch boundaries and extraordinary vertices; the limit
    /// or displaced surface; the input coloured by its distance to the limit
    /// surface (‰ of the diagonal; unprojectable regions in magenta).
    #[arg(long, value_enum, default_value_t = WhatArg::Input)]
    what: WhatArg,
    /// Viewpoint; `auto` picks the one showing the most surface.
    #[arg(long, value_enum, default_value_t = ViewArg::Auto)]
    view: ViewArg,
    /// Picture size, WIDTHxHEIGHT.
    #[arg(long, default_value = "1024x768")]
    size: String,
    /// Ray caster (both give the same picture).
    #[arg(long, value_enum, default_value_t = RaysArg::Embree)]
    rays: RaysArg,
    /// The PNG to write (atomically).
    #[arg(short, long)]
    output: PathBuf,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

pub fn run(a: RenderArgs) -> Result<ExitCode> {
    let (w, h) = parse_size(&a.size)?;
    let opts = RenderOptions::default()
        .with_what(match a.what {
            WhatArg::Input => What::Input,
            WhatArg::Fitmap => What::Fitmap,
            WhatArg::Patches => What::Patches,
            WhatArg::Limit => What::Limit,
            WhatArg::Displaced => What::Displaced,
            WhatArg::Error => What::Error,
        })
        .with_view(match a.view {
            ViewArg::Front => View::Front,
            ViewArg::Side => View::Side,
            ViewArg::Top => View::Top,
            ViewArg::Iso => View::Iso,
            ViewArg::Auto => View::Auto,
        })
        .with_size(w, h)
        .with_rays(match a.rays {
            RaysArg::Embree => RayBackend::Embree,
            RaysArg::Rust => RayBackend::Rust,
        });
    let mut bars = progress_bars(a.quiet);
    let img = render(&a.input, &opts, &mut |f| bars("render", f)).map_err(|e| {
        // Errors about a mesh name their file already; others get it.
        let name = a.input.display().to_string();
        let msg = e.to_string();
        if msg.contains(&name) {
            anyhow::anyhow!("{msg}")
        } else {
            anyhow::anyhow!("{name}: {msg}")
        }
    })?;
    img.write_png(&a.output)?;
    Ok(ExitCode::SUCCESS)
}
