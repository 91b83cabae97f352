//! fipt-train: the fipt command line.
//!
//! Owns: argument parsing and dispatch to the pipeline stages and tools. Must not touch: the
//! maths of any stage (that lives in fipt-core and fipt-bake).

use fipt_train::{bench, check};

use clap::{Parser, Subcommand};
use fipt_core::model::BackendKind;
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "fipt-train",
    version,
    about = "Factorized Inverse Path Tracing in Rust"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Dataset doctor: load a scene, cast every pixel-centre ray and report what is wrong.
    Check {
        #[arg(long)]
        scene: PathBuf,
        /// Print one JSON object instead of a human report.
        #[arg(long)]
        json: bool,
    },
    /// Print the default configuration (the reference constants) as JSON.
    DefaultConfig,
    /// Benchmarks (JSON out with --json).
    Bench {
        #[command(subcommand)]
        what: BenchCmd,
    },
}

#[derive(Subcommand)]
enum BenchCmd {
    /// Closest-hit rays per second, 1 and 2 threads, incoherent and camera rays.
    Trace {
        /// Scene folder; without it a built-in procedural room (>= 100k triangles) is used.
        #[arg(long)]
        scene: Option<PathBuf>,
        #[arg(long)]
        json: bool,
        /// Number of incoherent rays.
        #[arg(long, default_value_t = 4 << 20)]
        rays: usize,
        /// Timed repetitions per configuration (the median is reported).
        #[arg(long, default_value_t = 5)]
        reps: usize,
    },
    /// Median time of one stage-2 training step (reference and CPU-sized models).
    Step {
        /// Backend(s) to time: flex, ndarray, wgpu (default: flex and ndarray).
        #[arg(long)]
        backend: Vec<BackendKind>,
        #[arg(long)]
        json: bool,
        #[arg(long, default_value_t = 8192)]
        batch: usize,
        /// Timed steps (after 2 warm-up steps).
        #[arg(long, default_value_t = 10)]
        steps: usize,
    },
}

fn main() {
    let cli = Cli::parse();
    let res = match cli.cmd {
        Cmd::Check { scene, json } => check::run(&scene, json),
        Cmd::DefaultConfig => serde_json::to_string_pretty(&fipt_train::config::Config::default())
            .map(|s| println!("{s}"))
            .map_err(Into::into),
        Cmd::Bench { what } => match what {
            BenchCmd::Trace {
                scene,
                json,
                rays,
                reps,
            } => bench::trace(scene.as_deref(), json, rays, reps),
            BenchCmd::Step {
                backend,
                json,
                batch,
                steps,
            } => {
                let b = if backend.is_empty() {
                    vec![BackendKind::Flex, BackendKind::Ndarray]
                } else {
                    backend
                };
                bench::step(&b, json, batch, steps)
            }
        },
    };
    if let Err(e) = res {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}
