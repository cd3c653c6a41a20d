//! `metasplat aberrate`: the library's job ([`metasplat::jobs::aberrate`]), its report printed.

use anyhow::Result;

pub use metasplat::jobs::aberrate::AberrateRequest as AberrateArgs;

pub fn run(a: AberrateArgs) -> Result<()> {
    let (r, _) = super::progress::step("aberrating", || metasplat::jobs::aberrate::run(&a));
    let r = r?;
    let (w, h) = r.size;
    let mode = a.imaging.mode;
    if a.input.is_dir() {
        println!(
            "{} frames {w}x{h} through {} px PSFs ({mode} mode), noise seeded per frame: mean PSNR {:.2} dB vs input; wrote {}",
            r.frames,
            r.psf_px,
            r.psnr,
            r.out.display()
        );
    } else {
        println!(
            "{w}x{h} through a {g}x{g} grid of {} px PSFs ({mode} mode) in {:.2} s: PSNR {:.2} dB vs input; wrote {}",
            r.psf_px,
            r.seconds,
            r.psnr,
            r.out.display(),
            g = r.grid
        );
    }
    Ok(())
}
