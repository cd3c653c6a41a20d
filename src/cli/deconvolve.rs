//! `metasplat deconvolve`: the library's job ([`metasplat::jobs::deconvolve`]), its report
//! printed.

use anyhow::Result;

pub use metasplat::jobs::deconvolve::DeconvolveRequest as DeconvolveArgs;

pub fn run(a: DeconvolveArgs) -> Result<()> {
    let (r, _) = super::progress::step("deconvolving", || metasplat::jobs::deconvolve::run(&a));
    let r = r?;
    let score = |p: Option<f64>| p.map_or(String::new(), |p| format!(" ({p:.2} dB)"));
    if r.input_psnr.is_some() {
        println!("input{}", score(r.input_psnr));
    }
    if let (Some(bank), Some(dir)) = (&r.bank, &a.bank) {
        let secs = bank.seconds;
        for (m, (k, p)) in bank
            .filters
            .iter()
            .enumerate()
            .filter(|(_, (_, p))| p.is_some())
        {
            println!("filter {m:2} k {k:.1e}{}", score(*p));
        }
        println!(
            "MAFG bank (13 adaptive filters, k 1e-2..1e-5) in {secs:.2} s: wrote {}",
            dir.display()
        );
    }
    println!(
        "Wiener K = {:.2e}{} in {:.2} s{}: wrote {}",
        r.k,
        if a.k.is_none() { " (the default)" } else { "" },
        r.seconds,
        score(r.psnr),
        a.out.display()
    );
    Ok(())
}
