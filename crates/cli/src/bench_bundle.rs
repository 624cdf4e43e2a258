//! `handheld bench bundle`: placeholder until its stage crate lands.

use clap::Args;

use crate::args::GlobalArgs;
use crate::ui::Bars;

#[derive(Debug, Args)]
pub struct BenchBundleArgs {}

pub fn run(_a: &BenchBundleArgs, _g: &GlobalArgs, _bars: &Bars) -> anyhow::Result<()> {
    anyhow::bail!("handheld bench bundle is not built yet")
}
