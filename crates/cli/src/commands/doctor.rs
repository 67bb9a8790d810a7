//! `revisit doctor`: what Revisit runs on, found where, and whether it works.

use anyhow::{bail, Result};
use revisit_features::learned::{Aliked, XFeat, XFeatOptions};
use revisit_matching::LightGlue;
use revisit_pipeline::locate::Found;

use crate::commands::models::ToolArgs;

/// Checks Python with pycolmap, the ONNX Runtime library and every learned
/// model file against its contract (inputs, outputs, shapes), and prints one
/// line each: ready, or what is wrong and how to fix it. Exits non-zero if
/// anything is not ready.
#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    tools: ToolArgs,
}

/// The model files and the descriptor size of the features each matcher takes.
const MODELS: [(&str, Kind); 5] = [
    ("aliked_n16_480x640.onnx", Kind::Aliked),
    ("aliked_n16_600x800.onnx", Kind::Aliked),
    ("lightglue_aliked.onnx", Kind::Matcher(128)),
    ("xfeat_backbone.onnx", Kind::XFeat),
    ("lighterglue_xfeat.onnx", Kind::Matcher(64)),
];

#[derive(Clone, Copy)]
enum Kind {
    Aliked,
    XFeat,
    Matcher(usize),
}

pub fn run(args: Args) -> Result<()> {
    let tools = args.tools.tools();
    let mut problems = 0;
    let mut line = |what: &str, outcome: Result<String, String>| match outcome {
        Ok(detail) => println!("ready    {what:<26} {detail}"),
        Err(reason) => {
            problems += 1;
            println!("MISSING  {what:<26} {reason}");
        }
    };

    line(
        "python + pycolmap",
        tools.python().map_err(|e| e.to_string()).and_then(|python| {
            let version = std::process::Command::new(&python)
                .args(["-c", "import pycolmap; print(pycolmap.__version__)"])
                .output()
                .map_err(|e| e.to_string())?;
            Ok(format!("{} (pycolmap {})", python.display(), String::from_utf8_lossy(&version.stdout).trim()))
        }),
    );
    let runtime = tools.onnxruntime(1);
    line(
        "onnx runtime",
        match (&runtime, tools.find_onnxruntime()) {
            (Ok(_), Found::At(path)) => Ok(path.display().to_string()),
            (Err(e), _) => Err(e.to_string()),
            (Ok(_), missing) => Err(format!("not found (looked for {})", missing.looked())),
        },
    );
    let models = tools.models();
    match tools.find_models() {
        Found::At(dir) => line("models folder", Ok(dir.display().to_string())),
        missing => line(
            "models folder",
            Err(format!(
                "not found (looked for {}); run scripts/get-models.sh, or pass --models / set REVISIT_MODELS",
                missing.looked()
            )),
        ),
    }
    for (file, kind) in MODELS {
        let path = models.join(file);
        let outcome = match &runtime {
            Err(_) => Err("needs ONNX Runtime".to_owned()),
            Ok(runtime) => match kind {
                Kind::Aliked => Aliked::open(runtime, &path).map(|_| ()),
                Kind::XFeat => XFeat::open(runtime, &path, XFeatOptions::default()).map(|_| ()),
                Kind::Matcher(dim) => LightGlue::open(runtime, &path, dim).map(|_| ()),
            }
            .map(|()| format!("{} (contract checked)", path.display()))
            .map_err(|e| e.to_string()),
        };
        line(file, outcome);
    }
    if problems > 0 {
        bail!("{problems} of {} checks failed", 3 + MODELS.len());
    }
    println!("everything is ready");
    Ok(())
}
