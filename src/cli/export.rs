//! `metasplat export`: the library's job ([`metasplat::jobs::export`]) and what it wrote.

use anyhow::Result;
use metasplat::jobs::export::prepare;

pub use metasplat::jobs::export::ExportRequest as ExportArgs;

pub fn run(a: ExportArgs) -> Result<()> {
    let prepared = prepare(&a)?;
    if let Some(note) = &prepared.note {
        println!("{note}");
    }
    let r = prepared.run()?;
    println!(
        "Wrote {} splats (SH degree {}) to {}: {} bytes, {:.1} per splat.",
        r.splats,
        r.sh_degree,
        r.out.display(),
        r.bytes,
        r.bytes as f64 / r.splats.max(1) as f64
    );
    Ok(())
}
