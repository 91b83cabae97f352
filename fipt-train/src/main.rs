//! fipt-train: the fipt command line.
//!
//! Owns: argument parsing, dispatch and printing. Must not touch: the work of any command (that
//! lives in the library: `pipeline`, `check`, `bench`).

use fipt_train::{bench, check, pipeline};

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
    /// What to do (none: the built-in demo, as `fipt-train demo`).
    #[command(subcommand)]
    cmd: Option<Cmd>,
}

/// The scene, output folder, config and seed of a pipeline job (`bake`, `run`).
#[derive(clap::Args)]
struct JobArgs {
    #[arg(long)]
    scene: PathBuf,
    #[arg(long)]
    out: PathBuf,
    /// Config file (JSON); defaults to `configs/default.json`'s values.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Overrides the config's seed.
    #[arg(long)]
    seed: Option<u64>,
}

impl JobArgs {
    /// The config file (or the defaults) with the seed override applied.
    fn config(&self) -> anyhow::Result<fipt_train::config::Config> {
        let mut cfg = match &self.config {
            Some(p) => fipt_train::config::Config::load(p)?,
            None => fipt_train::config::Config::default(),
        };
        if let Some(s) = self.seed {
            cfg.seed = s;
        }
        Ok(cfg)
    }
}

#[derive(Subcommand)]
enum Cmd {
    /// The built-in demo: renders a room the project describes itself (cached), runs the whole
    /// method on it and writes the report. No files from outside the repository.
    Demo {
        /// Output folder (the scene in OUT/scene, the run in OUT/run, the zoo in OUT/zoo).
        #[arg(long, default_value = "demo")]
        out: PathBuf,
        /// No progress bars and no summary.
        #[arg(long)]
        quiet: bool,
    },
    /// Dataset doctor: load a scene, cast every pixel-centre ray and report what is wrong.
    Check {
        #[arg(long)]
        scene: PathBuf,
        /// Print one JSON object instead of a human report.
        #[arg(long)]
        json: bool,
    },
    /// The bake alone: L′, the baked and filtered shadings (cached), EXR and PNG outputs.
    Bake {
        #[command(flatten)]
        job: JobArgs,
        /// No progress bar; print the report as JSON.
        #[arg(long)]
        json: bool,
    },
    /// The pipeline: bake (cached) → fit → emitters → maps → metrics.
    Run {
        #[command(flatten)]
        job: JobArgs,
        /// Backend: flex, wgpu or ndarray (overrides the config; wgpu and ndarray need their cargo
        /// feature).
        #[arg(long)]
        backend: Option<BackendKind>,
        /// No progress bars; print metrics.json to stdout.
        #[arg(long)]
        json: bool,
        /// Fit the oracle shadings (path-traced with the scene's true materials and emitters)
        /// instead of the baked ones, without refinement: the factorised model's ceiling.
        #[arg(long)]
        oracle: bool,
        /// The zoo to register the scene model in (default: $FIPT_ZOO, else zoo/ beside OUT).
        #[arg(long)]
        zoo: Option<PathBuf>,
        /// The model's name in the zoo (default: <scene folder>-s<seed>).
        #[arg(long)]
        name: Option<String>,
        /// Do not register the model in a zoo (it is still written to OUT/model).
        #[arg(long, conflicts_with_all = ["zoo", "name"])]
        no_zoo: bool,
    },
    /// Diagnostic: the per-part loss landscape over roughness at the true base colour and
    /// metallic, for the baked shadings, every refined round cached in OUT and the oracle.
    Landscape {
        #[command(flatten)]
        job: JobArgs,
        /// Also compute (and cache) the oracle shadings.
        #[arg(long)]
        oracle: bool,
        /// Also sweep at the base colour and metallic of the model in OUT/maps/train (left by
        /// `run`), beside its own data term.
        #[arg(long)]
        fitted: bool,
        /// Print landscape.json to stdout instead of tables.
        #[arg(long)]
        json: bool,
        /// With `train.min_coverage` τ > 0: measure a pixel's coverage by the plane of the mesh
        /// its centre ray hits instead of by its part, so that pixels split between two faces
        /// of one part (a box's edge) leave too.
        #[arg(long)]
        cover_planes: bool,
        /// Also the shadings with part of the oracle swapped for the model in OUT/model (left
        /// by `run`): its materials with its emitters, with the true emitters, and the true
        /// materials with its emitters, each through the oracle's paths and radiance cache.
        #[arg(long)]
        swap: bool,
        /// With --swap, also the true scene with this part's material the model's (a name in
        /// scene_meta.json; repeat the flag or separate names with commas).
        #[arg(long, value_delimiter = ',', requires = "swap")]
        swap_part: Vec<String>,
    },
    /// Recompute the metrics from the maps a previous `run` saved (or, with --model, from a
    /// scene model's predictions).
    Eval {
        #[arg(long)]
        scene: PathBuf,
        #[arg(long)]
        out: PathBuf,
        /// Score this scene model (a folder or a zoo name) instead of OUT's saved maps.
        #[arg(long)]
        model: Option<String>,
        /// The zoo folder (default: $FIPT_ZOO, else ./zoo).
        #[arg(long)]
        zoo: Option<PathBuf>,
        /// Print eval.json to stdout instead of the tables.
        #[arg(long)]
        json: bool,
    },
    /// Path-traced images: of a recovered scene model (`--model`) or of the true scene
    /// (`--truth`), from a split's cameras or new ones, relit, with inserted objects.
    #[command(group(clap::ArgGroup::new("source").required(true).args(["truth", "model"])))]
    Render(RenderArgs),
    /// A recovered scene model (`--model`) or a scene's ground truth (`--truth`) as glTF 2.0
    /// and Mitsuba 3 files: the field baked into textures over a UV atlas, one material per
    /// part, emitters with their radiance, the cameras of one split (the val views by default).
    #[command(group(clap::ArgGroup::new("source").required(true).args(["truth", "model"])))]
    Export {
        /// A scene model folder, or a name in the zoo.
        #[arg(long)]
        model: Option<String>,
        /// Export the true scene of --scene (materials, textures and emitters of
        /// scene_meta.json).
        #[arg(long)]
        truth: bool,
        /// The scene folder: its parts and cameras (default for a model: the folder it was
        /// recovered from, where it still exists).
        #[arg(long)]
        scene: Option<PathBuf>,
        /// The split whose views become the cameras (`<split>_NNN`): val, or train, whose
        /// renders stand in for the photos.
        #[arg(long, value_enum, default_value_t = fipt_train::export::CameraSplit::Val)]
        split: fipt_train::export::CameraSplit,
        /// glb (one file), gltf (.gltf + .bin + PNGs), mitsuba (scene.xml + PLY + PNGs) or
        /// viewer (scene.glb with an offline WebGL viewer page); repeat or comma-separate.
        #[arg(long, value_delimiter = ',', required = true)]
        format: Vec<fipt_train::export::Format>,
        #[arg(long)]
        out: PathBuf,
        /// Side of the square textures, in texels.
        #[arg(long, default_value_t = 2048, value_parser = flag_range(*fipt_train::export::TEXELS.start(), *fipt_train::export::TEXELS.end()))]
        texels: usize,
        /// Where a model's field is queried: flex (host) or wgpu.
        #[arg(long, default_value = "flex")]
        backend: BackendKind,
        /// The zoo folder (default: $FIPT_ZOO, else ./zoo).
        #[arg(long)]
        zoo: Option<PathBuf>,
        /// Print export.json instead of a summary.
        #[arg(long)]
        json: bool,
    },
    /// The LDR twin of an HDR scene: every photo through a camera response, an exposure per
    /// view and 8-bit PNG or JPEG, the rest of the folder unchanged; OUT/ldr.json holds the
    /// truth.
    Ldr {
        /// The HDR scene folder.
        #[arg(long)]
        scene: PathBuf,
        #[arg(long)]
        out: PathBuf,
        /// The response: srgb, gamma:G or gamma:R,G,B.
        #[arg(long, default_value = "srgb")]
        response: fipt_train::ldr::twin::CurveSpec,
        /// The base exposure (default: the one that clips --clip of the train pixels and every
        /// true emitter pixel).
        #[arg(long)]
        exposure: Option<f64>,
        /// The share of train pixels the default exposure clips at least.
        #[arg(long, default_value_t = 0.01)]
        clip: f64,
        /// Each view's exposure is 2^u times the base, u uniform in [-STOPS, STOPS].
        #[arg(long, default_value_t = 0.0)]
        stops: f64,
        /// Write each frame's relative exposure as `exposure` in transforms.json.
        #[arg(long)]
        give_exposure: bool,
        #[arg(long, value_enum, default_value = "png")]
        format: fipt_train::ldr::twin::LdrFormat,
        /// JPEG quality.
        #[arg(long, default_value_t = 90, value_parser = flag_range(1, 100))]
        quality: usize,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Print ldr.json instead of a summary.
        #[arg(long)]
        json: bool,
    },
    /// The model zoo: scene models recovered by `run`, by name.
    Zoo {
        /// The zoo folder (default: $FIPT_ZOO, else ./zoo).
        #[arg(long, global = true)]
        zoo: Option<PathBuf>,
        #[command(subcommand)]
        what: ZooCmd,
    },
    /// (Re)builds the HTML report (OUT/report.html) of a finished run.
    Report {
        #[arg(long)]
        scene: PathBuf,
        #[arg(long)]
        out: PathBuf,
    },
    /// The scene suite: rooms drawn at random (cached), the whole method on each, figures per
    /// scene and part and per half (even seeds tune, odd seeds are held out); resumable.
    Suite {
        /// Output folder (scenes in OUT/scenes, runs in OUT/runs, OUT/suite.json).
        #[arg(long, default_value = "out/suite")]
        out: PathBuf,
        /// Number of scenes (seeds FIRST_SEED ..).
        #[arg(long, default_value_t = 8, value_parser = flag_range(1, 1000))]
        scenes: usize,
        #[arg(long, default_value_t = 0)]
        first_seed: u64,
        /// Scene size: full (160x120, 30-60 views) or small (96x72, 16 views).
        #[arg(long, value_enum, default_value_t = fipt_train::suite::SceneSize::Full)]
        size: fipt_train::suite::SceneSize,
        /// Samples per pixel of the scenes' photos (default: the size's, 512 for full and
        /// 1024 for small). Fewer render sooner and give noisier photos.
        #[arg(long, value_parser = flag_range(1, 1 << 20))]
        spp: Option<usize>,
        /// Config file (JSON); defaults to `configs/default.json`'s values.
        #[arg(long)]
        config: Option<PathBuf>,
        /// No progress bars; print suite.json to stdout.
        #[arg(long)]
        json: bool,
    },
    /// Print the default configuration (`configs/default.json`) as JSON.
    DefaultConfig,
    /// Benchmarks (JSON out with --json).
    Bench {
        #[command(subcommand)]
        what: BenchCmd,
    },
}

/// The flags of `render`.
#[derive(clap::Args)]
struct RenderArgs {
    /// The scene folder: its cameras, reference images and ground truth (required with
    /// --truth; with --model, for its cameras and scores).
    #[arg(long)]
    scene: Option<PathBuf>,
    #[arg(long)]
    out: PathBuf,
    /// Render the true scene (materials, textures and emitters of scene_meta.json).
    #[arg(long)]
    truth: bool,
    /// Render a recovered scene model: a model folder, or a name in the zoo.
    #[arg(long)]
    model: Option<String>,
    /// Where a model's field is queried: flex (host), or wgpu (the table on the device;
    /// needs the cargo feature).
    #[arg(long, default_value = "flex")]
    backend: BackendKind,
    /// The zoo folder (default: $FIPT_ZOO, else ./zoo).
    #[arg(long)]
    zoo: Option<PathBuf>,
    /// Objects to insert (JSON: OBJ files or shapes, placement, material or emission).
    #[arg(long)]
    insert: Option<PathBuf>,
    /// Pure path tracing: no L′ on rough secondary hits (models; relighting never uses it).
    #[arg(long)]
    no_cache: bool,
    /// Read the exact learned field at every hit (default: a voxel cache after the first
    /// segment; camera hits are always exact).
    #[arg(long)]
    exact_materials: bool,
    /// Relighting: switched-off emitters are black (the reference) instead of reflecting
    /// with the learned field.
    #[arg(long)]
    off_black: bool,
    /// Models: fixed sub-pixel positions per pixel (a square; 0: continuous jitter), so
    /// the exact field is queried once per position, not per sample.
    #[arg(long, default_value_t = 16, value_parser = flag_range(0, 4096))]
    pixel_positions: usize,
    /// Which cameras: train or val.
    #[arg(long, default_value = "val")]
    split: String,
    /// Only these views (comma-separated; default all).
    #[arg(long, value_delimiter = ',', value_parser = flag_range(0, 1 << 20))]
    views: Vec<usize>,
    /// New cameras from a transforms.json (FIPT or nerfstudio) instead of the split's.
    #[arg(long)]
    cameras: Option<PathBuf>,
    #[arg(long, default_value_t = 512, value_parser = flag_range(1, 65536))]
    spp: usize,
    /// Maximum path length in segments (Mitsuba's max_depth).
    #[arg(long, default_value_t = 7, value_parser = flag_range(1, 64))]
    max_depth: usize,
    /// relight.json: emitters off or rescaled (part names or "all") and new emitters
    /// added; renders go to Relight/.
    #[arg(long)]
    relight: Option<PathBuf>,
    /// Emitter selection for next-event estimation: uniform, area or power.
    #[arg(long, default_value = "power")]
    light_selection: fipt_bake::emitters::LightSelection,
    /// Russian roulette from this depth on (default off).
    #[arg(long)]
    rr_depth: Option<usize>,
    /// BRDF lobe choice: luminance (by lobe reflectance) or half (the reference's 50/50).
    #[arg(long, default_value = "luminance")]
    lobe: fipt_core::brdf::LobeChoice,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// No progress bar; print render.json to stdout.
    #[arg(long)]
    json: bool,
}

impl RenderArgs {
    /// The render job these flags ask for.
    fn job(self) -> anyhow::Result<fipt_train::rerender::RenderJob> {
        let p = self.pixel_positions;
        if p.isqrt().pow(2) != p {
            anyhow::bail!("--pixel-positions {p}: must be a square (0, 1, 4, 9, 16, ...)");
        }
        let source = match self.model {
            Some(name_or_dir) => fipt_train::rerender::Source::Model {
                name_or_dir,
                zoo: fipt_train::zoo::working(self.zoo.as_deref()),
            },
            None => fipt_train::rerender::Source::Truth,
        };
        Ok(fipt_train::rerender::RenderJob {
            scene: self.scene,
            out: self.out,
            source,
            split: self.split,
            views: self.views,
            cameras: self.cameras,
            relight: self.relight,
            insert: self.insert,
            cache: !self.no_cache,
            material_cache: !self.exact_materials,
            off_reflect: !self.off_black,
            selection: self.light_selection,
            path: fipt_bake::integrators::path::PathConfig {
                spp: self.spp,
                max_depth: self.max_depth,
                rr_depth: self.rr_depth,
                lobe: self.lobe,
                seed: self.seed,
                pixel_positions: p,
                ..Default::default()
            },
            quiet: self.json,
            backend: self.backend,
        })
    }
}

#[derive(Subcommand)]
enum ZooCmd {
    /// Name, scene, date, size and headline metrics of every model.
    List {
        #[arg(long)]
        json: bool,
    },
    /// One model's manifest (after checking every file against it).
    Show { name: String },
    /// Removes a model.
    Rm { name: String },
    /// Copies a model folder into the zoo after loading it fully.
    Import {
        dir: PathBuf,
        /// The name in the zoo (default: the model's own).
        #[arg(long)]
        name: Option<String>,
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
        #[arg(long, default_value_t = 4 << 20, value_parser = flag_range(1, 1 << 28))]
        rays: usize,
        /// Timed repetitions per configuration (the median is reported).
        #[arg(long, default_value_t = 5, value_parser = flag_range(1, 1000))]
        reps: usize,
        /// Split every triangle into 4^K by midpoint subdivision (the same surface), as the
        /// peer script's `--mesh-scale`: throughput against triangle count.
        #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=6))]
        mesh_scale: u32,
    },
    /// Paths and rays per second of the path tracer on a scene's true materials, 1 and 2 threads.
    Render {
        #[arg(long)]
        scene: PathBuf,
        #[arg(long)]
        json: bool,
        #[arg(long, default_value_t = 16, value_parser = flag_range(1, 65536))]
        spp: usize,
        #[arg(long, default_value_t = 2, value_parser = flag_range(1, 1000))]
        views: usize,
        #[arg(long, default_value_t = 3, value_parser = flag_range(1, 1000))]
        reps: usize,
    },
    /// The refinement of a few train views of a finished run with the voxel material cache
    /// and with exact queries of the learned field: time and the difference of the shadings.
    Refine {
        #[arg(long)]
        scene: PathBuf,
        /// The output folder of a finished `run` (model, emitters, bake cache, config).
        #[arg(long)]
        run: PathBuf,
        #[arg(long)]
        json: bool,
        #[arg(long, default_value_t = 2, value_parser = flag_range(1, 1000))]
        views: usize,
    },
    /// Material queries per second of a scene model's learned field: exact and through the
    /// voxel cache that rendering uses after the first segment.
    Query {
        /// A scene model folder or a zoo name.
        #[arg(long)]
        model: String,
        /// The zoo folder (default: $FIPT_ZOO, else ./zoo).
        #[arg(long)]
        zoo: Option<PathBuf>,
        #[arg(long)]
        json: bool,
        /// Points per query (the path tracer's wavefronts hold up to 2^18).
        #[arg(long, default_value_t = 1 << 18, value_parser = flag_range(1, 1 << 24))]
        batch: usize,
        #[arg(long, default_value_t = 5, value_parser = flag_range(1, 1000))]
        reps: usize,
    },
    /// Secondary rays per second of the bake on a built-in scene.
    Bake {
        #[arg(long)]
        json: bool,
        #[arg(long, default_value_t = 3, value_parser = flag_range(1, 1000))]
        reps: usize,
    },
    /// Median time of one training step of the fit (reference and CPU-sized models, part and
    /// semantic losses, shuffled batches of a realistic pixel store).
    Step(fipt_train::bench::step::StepArgs),
}

/// A flag's allowed integers: clap refuses any other value naming the flag and the range.
pub fn flag_range(lo: u64, hi: u64) -> clap::builder::RangedU64ValueParser<usize> {
    clap::builder::RangedU64ValueParser::<usize>::new().range(lo..=hi)
}

fn main() {
    // burn puts some state on its default device, where no device is passed: the optimiser's,
    // when a fit resumes; the next step moves it to the run's device. That default prefers a
    // GPU when the wgpu backend is compiled in, so a resumed CPU run would start one. It is the
    // CPU here unless the user names another.
    if std::env::var_os("BURN_DEVICE").is_none() {
        // SAFETY: the first statement of main, before any other thread exists.
        unsafe { std::env::set_var("BURN_DEVICE", "flex") };
    }
    fipt_train::alloc::tune();
    let cli = Cli::parse();
    let cmd = cli.cmd.unwrap_or(Cmd::Demo {
        out: PathBuf::from("demo"),
        quiet: false,
    });
    // Ctrl-C asks the long commands to stop at a safe point (`interrupt`).
    let stoppable = matches!(
        cmd,
        Cmd::Demo { .. } | Cmd::Run { .. } | Cmd::Suite { .. } | Cmd::Bake { .. } | Cmd::Render(_)
    );
    if stoppable {
        fipt_train::interrupt::install();
    } else {
        fipt_train::interrupt::install_quit();
    }
    let done = dispatch(cmd);
    // A Ctrl-C after the last safe point: the outputs are whole, the command still says so.
    if done.is_ok() && stoppable && fipt_train::interrupt::requested() {
        eprintln!("interrupted after the command's outputs were complete");
        std::process::exit(130);
    }
    if let Err(e) = done {
        if let Some(i) = e.downcast_ref::<fipt_train::interrupt::Interrupted>() {
            eprintln!("{i}");
            std::process::exit(130);
        }
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

/// Runs one command.
fn dispatch(cmd: Cmd) -> anyhow::Result<()> {
    match cmd {
        // Without --quiet the run has printed the report's path as its last line already.
        Cmd::Demo { out, quiet } => fipt_train::demo::demo(&out, quiet).map(|p| {
            if quiet {
                println!("report: {}", p.display());
            }
        }),
        Cmd::Check { scene, json } => check::run(&scene, json),
        Cmd::Bake { job, json } => {
            let r = pipeline::bake_cmd::bake_job(&job.scene, &job.out, &job.config()?, json)?;
            print_json_or(json, &r, || r.print())
        }
        Cmd::Landscape {
            job,
            oracle,
            fitted,
            json,
            cover_planes,
            swap,
            swap_part,
        } => {
            let cfg = job.config()?;
            let what = pipeline::landscape_cmd::Tables {
                oracle,
                fitted,
                cover_planes,
                swap: swap.then_some(swap_part),
            };
            let tables = pipeline::landscapes(&job.scene, &job.out, &cfg, what, json)?;
            if json {
                println!(
                    "{}",
                    std::fs::read_to_string(job.out.join("landscape.json"))?
                );
            } else {
                pipeline::landscape_cmd::print_tables(&tables);
            }
            Ok(())
        }
        Cmd::Run {
            job,
            backend,
            json,
            oracle,
            zoo,
            name,
            no_zoo,
        } => {
            let mut cfg = job.config()?;
            if let Some(b) = backend {
                cfg.backend = b;
            }
            let zoo = if no_zoo {
                None
            } else {
                let dir =
                    fipt_train::zoo::resolve(zoo.as_deref(), &fipt_train::zoo::beside(&job.out));
                let name =
                    name.unwrap_or_else(|| pipeline::default_model_name(&job.scene, cfg.seed));
                fipt_train::zoo::check_name(&name)?;
                Some((dir, name))
            };
            let opts = pipeline::RunOptions {
                quiet: json,
                oracle,
                zoo,
            };
            let r = pipeline::run_with(&job.scene, &job.out, &cfg, &opts)?;
            print_json_or(json, &r, || {})
        }
        Cmd::Zoo { zoo, what } => zoo_cmd(zoo, what),
        Cmd::Report { scene, out } => fipt_train::html_report::write(&scene, &out)
            .map(|p| println!("report: {}", p.display())),
        Cmd::Eval {
            scene,
            out,
            model,
            zoo,
            json,
        } => {
            let r = match model {
                Some(m) => {
                    let dir = fipt_train::zoo::Zoo::new(fipt_train::zoo::working(zoo.as_deref()))
                        .locate(&m)?;
                    pipeline::eval_model(&scene, &dir, &out)?
                }
                None => pipeline::eval(&scene, &out)?,
            };
            print_json_or(json, &r, || {
                pipeline::report::print_metrics(&r.metrics, r.parts.as_deref())
            })
        }
        Cmd::Render(args) => {
            let json = args.json;
            let job = args.job()?;
            let r = fipt_train::rerender::render(&job)?;
            print_json_or(json, &r, || r.print(&job.out))
        }
        Cmd::Export {
            model,
            truth: _,
            scene,
            split,
            format,
            out,
            texels,
            backend,
            zoo,
            json,
        } => {
            let source = match model {
                Some(name_or_dir) => fipt_train::export::Source::Model {
                    name_or_dir,
                    zoo: fipt_train::zoo::working(zoo.as_deref()),
                },
                None => fipt_train::export::Source::Truth,
            };
            let job = fipt_train::export::ExportJob {
                source,
                scene,
                split,
                formats: format,
                out: out.clone(),
                texels,
                backend,
                quiet: json,
            };
            let r = fipt_train::export::export(&job)?;
            print_json_or(json, &r, || {
                println!(
                    "{}: {} files, {} materials, {} emitting triangles, {} cameras, {}² texels ({:.0} % used) in {:.1} s",
                    out.display(),
                    r.files.len(),
                    r.materials.len(),
                    r.emitter_triangles,
                    r.cameras,
                    r.texels,
                    100.0 * r.coverage,
                    r.seconds
                )
            })
        }
        Cmd::Suite {
            out,
            scenes,
            first_seed,
            size,
            spp,
            config,
            json,
        } => {
            let config = match &config {
                Some(p) => fipt_train::config::Config::load(p)?,
                None => fipt_train::config::Config::default(),
            };
            let job = fipt_train::suite::SuiteJob {
                out,
                first_seed,
                scenes,
                size,
                spp,
                config,
                quiet: json,
            };
            let r = fipt_train::suite::run_suite(&job)?;
            print_json_or(json, &r, || {})
        }
        Cmd::Ldr {
            scene,
            out,
            response,
            exposure,
            clip,
            stops,
            give_exposure,
            format,
            quality,
            seed,
            json,
        } => {
            let job = fipt_train::ldr::TwinJob {
                scene,
                out: out.clone(),
                response,
                exposure,
                clip_share: clip,
                stops,
                give_exposure,
                format,
                quality: quality as u8,
                seed,
            };
            let t = fipt_train::ldr::make_twin(&job)?;
            print_json_or(json, &t, || {
                for s in &t.splits {
                    let n = s.clipped_share.len().max(1) as f64;
                    let lamps: Vec<f64> = s.emitter_clipped.iter().flatten().copied().collect();
                    println!(
                        "{}/{}: {} frames, {:.2} % of pixels clipped, lamps clipped in {} of {} views that show one (worst {:.0} % of a view's lamp pixels)",
                        out.display(),
                        s.name,
                        s.exposures.len(),
                        100.0 * s.clipped_share.iter().sum::<f64>() / n,
                        lamps.iter().filter(|&&x| x >= 0.99).count(),
                        lamps.len(),
                        100.0 * lamps.iter().cloned().fold(1.0, f64::min)
                    );
                }
            })
        }
        Cmd::DefaultConfig => print_json_or(true, &fipt_train::config::Config::default(), || {}),
        Cmd::Bench { what } => bench_cmd(what),
    }
}

/// Prints `v` as pretty JSON with `json`, else calls `human`.
fn print_json_or(
    json: bool,
    v: &impl serde::Serialize,
    human: impl FnOnce(),
) -> anyhow::Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(v)?);
    } else {
        human();
    }
    Ok(())
}

/// `zoo list | show | rm | import`.
fn zoo_cmd(zoo: Option<PathBuf>, what: ZooCmd) -> anyhow::Result<()> {
    let z = fipt_train::zoo::Zoo::new(fipt_train::zoo::working(zoo.as_deref()));
    match what {
        ZooCmd::List { json } => {
            let entries = z.list()?;
            print_json_or(json, &entries, || {
                println!("zoo: {}", z.dir.display());
                fipt_train::zoo::print_list(&entries);
            })
        }
        ZooCmd::Show { name } => {
            let dir = z.locate(&name)?;
            let m = fipt_train::scene_model::read_manifest(&dir)?;
            fipt_train::scene_model::verify_files(&dir, &m)?;
            print_json_or(true, &m, || {})
        }
        ZooCmd::Rm { name } => z.remove(&name).map(|_| {
            println!("removed {}", z.dir.join(&name).display());
        }),
        ZooCmd::Import { dir, name } => z.import(&dir, name.as_deref()).map(|to| {
            println!("imported {} as {}", dir.display(), to.display());
        }),
    }
}

/// `bench trace | bake | refine | render | query | step`.
fn bench_cmd(what: BenchCmd) -> anyhow::Result<()> {
    match what {
        BenchCmd::Trace {
            scene,
            json,
            rays,
            reps,
            mesh_scale,
        } => bench::trace::trace(scene.as_deref(), json, rays, reps, mesh_scale),
        BenchCmd::Bake { json, reps } => bench::bake::bake(json, reps),
        BenchCmd::Refine {
            scene,
            run,
            json,
            views,
        } => bench::refine::refine(&scene, &run, json, views),
        BenchCmd::Render {
            scene,
            json,
            spp,
            views,
            reps,
        } => bench::render::render(&scene, json, spp, views, reps),
        BenchCmd::Query {
            model,
            zoo,
            json,
            batch,
            reps,
        } => {
            let dir = fipt_train::zoo::Zoo::new(fipt_train::zoo::working(zoo.as_deref()))
                .locate(&model)?;
            bench::query::query(&dir, json, batch, reps)
        }
        BenchCmd::Step(args) => bench::step::step(&args),
    }
}
