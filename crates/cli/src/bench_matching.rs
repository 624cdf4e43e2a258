//! `handheld bench matching`: placeholder until its stage crate lands.

use clap::Args;

use crate::args::GlobalArgs;
use crate::ui::Bars;

#[derive(Debug, Args)]
pub struct BenchMatchingArgs {}

pub fn run(_a: &BenchMatchingArgs, _g: &GlobalArgs, _bars: &Bars) -> anyhow::Result<()> {
    anyhow::bail!("handheld bench matching is not built yet")
}
