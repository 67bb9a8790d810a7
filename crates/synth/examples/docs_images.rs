//! Regenerates the sample renders in `docs/images/` (320x240, downscaled from
//! 640x480): the same place in sessions 1 and 3 with change "strong", and in
//! sessions 1 and 2 with change "storm".
//! `cargo run --release -p revisit-synth --example docs_images -- docs/images`
use image::imageops::{resize, FilterType};
use revisit_synth::{plan, ChangeGrade, SynthOptions};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args().nth(1).unwrap_or_else(|| "docs/images".into());
    std::fs::create_dir_all(&out)?;
    for (change, later) in [(ChangeGrade::Strong, 2usize), (ChangeGrade::Storm, 1)] {
        let survey = plan(&SynthOptions { change, ..Default::default() })?;
        let first = survey.sessions()[0].images.len() / 2 + 3;
        let centre = survey.image(first)?.cam_from_world.origin_of_target();
        // The image of the later session whose camera is nearest.
        let offset: usize = survey.sessions()[..later].iter().map(|s| s.images.len()).sum();
        let nearest = (0..survey.sessions()[later].images.len())
            .min_by(|&a, &b| {
                let d = |i: usize| {
                    let c = survey.sessions()[later].images[i].cam_from_world.origin_of_target();
                    (c.x - centre.x).hypot(c.y - centre.y)
                };
                d(a).total_cmp(&d(b))
            })
            .unwrap_or(0);
        for (index, session) in [(first, 0), (offset + nearest, later)] {
            let rendered = survey.render(index)?;
            let small = resize(&rendered.rgb, 320, 240, FilterType::Triangle);
            let name = format!("{out}/reef_{change}_{}.png", survey.sessions()[session].name);
            small.save(&name)?;
            println!("{name} <- {}", survey.image(index)?.name);
        }
    }
    Ok(())
}
