//! Renders a few images of a survey into a folder and prints timings.
//! `cargo run --release -p revisit-synth --example preview -- OUT [change] [w h] [images...]`
use std::time::Instant;

/// User + system CPU seconds of this process (Linux).
fn cpu_secs() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let fields: Vec<&str> = stat.rsplit(')').next().unwrap_or("").split_whitespace().collect();
    let ticks = |i: usize| fields.get(i).and_then(|s| s.parse::<f64>().ok()).unwrap_or(0.0);
    (ticks(11) + ticks(12)) / 100.0
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let out = args.get(1).cloned().unwrap_or_else(|| "/tmp/synth-preview".into());
    let change = args.get(2).map_or(Ok(revisit_synth::ChangeGrade::Mild), |s| s.parse())?;
    let width = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(640);
    let height = args.get(4).and_then(|s| s.parse().ok()).unwrap_or(480);
    let options = revisit_synth::SynthOptions { change, width, height, ..Default::default() };
    std::fs::create_dir_all(&out)?;
    let t = Instant::now();
    let survey = revisit_synth::plan(&options)?;
    println!("plan {:.2}s site {:.1} m", t.elapsed().as_secs_f64(), survey.site_size_m());
    for s in survey.sessions() {
        println!(
            "{} alt {:.2} heading {:.1} lines {} n {}",
            s.name,
            s.altitude_m,
            s.heading_deg,
            s.lines,
            s.images.len()
        );
    }
    let t = Instant::now();
    let cpu = cpu_secs();
    for s in 0..survey.sessions().len() {
        survey.prepare(s)?;
    }
    println!("prepare {:.2}s wall, {:.1} CPU s", t.elapsed().as_secs_f64(), cpu_secs() - cpu);
    let picks: Vec<usize> = if args.len() > 5 {
        args[5..].iter().filter_map(|s| s.parse().ok()).collect()
    } else {
        vec![0, 25, 60, 85, 120, 145]
    };
    let t = Instant::now();
    let cpu = cpu_secs();
    for &i in &picks {
        let r = survey.render(i)?;
        let im = survey.image(i)?;
        r.rgb.save(format!("{out}/{}", im.name.replace('/', "_")))?;
    }
    let secs = t.elapsed().as_secs_f64();
    let cpu = cpu_secs() - cpu;
    println!(
        "rendered {} in {:.2}s = {:.1} img/s; {:.3} CPU s per image",
        picks.len(),
        secs,
        picks.len() as f64 / secs,
        cpu / picks.len() as f64
    );
    Ok(())
}
