//! `ppb plan`: a render's farm tasks, task index -> frame and pass range.
use anyhow::Result;
use clap::Args;
use std::process::ExitCode;

use super::farm::TaskFlags;

#[derive(Args)]
pub struct PlanArgs {
    #[command(flatten)]
    pub tasks: TaskFlags,
    /// Print JSON: {"tasks": N, "frames": ..., "passes": ..., "passes_per_task": ...,
    /// "list": [{"index", "frame", "passes": {"start", "end"}}]}.
    #[arg(long)]
    pub json: bool,
}

pub fn plan(args: PlanArgs) -> Result<ExitCode> {
    let (_, tasks) = args.tasks.tasks()?;
    if args.json {
        let list: Vec<_> = tasks.all().collect();
        let json = serde_json::json!({
            "tasks": tasks.count(),
            "frames": tasks.frames,
            "passes": tasks.passes,
            "passes_per_task": tasks.passes_per_task,
            "list": list,
        });
        println!("{json}");
        return Ok(ExitCode::SUCCESS);
    }
    println!(
        "{} tasks: {} frame(s) x {} task(s) of up to {} passes ({} passes per frame)",
        tasks.count(),
        tasks.frames.len(),
        tasks.per_frame(),
        tasks.passes_per_task,
        tasks.passes
    );
    for t in tasks.all() {
        match t.frame {
            Some(f) => println!("task {}: frame {f}, passes {}", t.index, t.passes),
            None => println!("task {}: passes {}", t.index, t.passes),
        }
    }
    Ok(ExitCode::SUCCESS)
}
