//! `driftid`: identify the drift coefficients of a space-stable INS's gyros from its own
//! accelerometers — simulate, record, replay, identify, diagnose, report.

use clap::{Parser, Subcommand};
use host_tool::cli;

#[derive(Parser, Debug)]
#[command(
    name = "driftid",
    version,
    about = "Gyro drift identification for space-stable inertial navigation systems",
    long_about = None,
    after_help = "Exit status: 0 the result is trusted by the tool's own checks; 3 numbers were computed but are not trusted (printed, with the reasons); 2 usage error, or input that is unreadable or cannot support an estimate (the error names the file, line or sample)."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// The most memory driftid's heap may hold, MiB [1, 2^30]; a block beyond it ends the
    /// command with exit 2 and a message. Default: 80 % of the memory free when it starts
    /// (MemAvailable, or the cgroup's room if less).
    #[arg(long, global = true, value_parser = cli::args::memory_mib, value_name = "MIB")]
    max_memory_mib: Option<usize>,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// The paper's case end to end in seconds: simulate, identify, compare with the paper's Table 2.
    Demo(cli::demo::DemoArgs),
    /// Simulate a platform run (truth model) and write a recording plus NAME.truth.json.
    Simulate(cli::simulate::SimulateArgs),
    /// Identify the drift coefficients of a recording, with 1σ and the Cramér–Rao bound.
    Identify(cli::identify::IdentifyArgs),
    /// The initial orientation of the next run (or a first pair) that best pins down what the runs so far leave weak.
    Plan(cli::plan::PlanArgs),
    /// Compare the model with the measurements, rank the missing effects, climb the model ladder.
    Diagnose(cli::diagnose::DiagnoseArgs),
    /// The whole story as one self-contained HTML page: model vs data, where it fails, the ranking, the ladder.
    Report(cli::report::ReportArgs),
    /// Record the navigation computer's telemetry (serial port) to a recording CSV and a raw frame log.
    Record(cli::record::RecordArgs),
    /// Stream a recording into the firmware over the link (hardware-in-the-loop) and record what comes back.
    Replay(cli::replay::ReplayArgs),
    /// Benchmarks: accuracy against the Cramér–Rao bound, false-alarm calibration, detection sensitivity.
    Bench(cli::bench::BenchArgs),
}

/// Huge pages for the large blocks ([`host_tool::heap`]).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[global_allocator]
static ALLOC: host_tool::heap::HugePages = host_tool::heap::HugePages;

fn main() {
    host_tool::progress::start_clock();
    // A closed stdout (`driftid identify … | head`) ends the process quietly, as for any Unix
    // filter: Rust ignores SIGPIPE, so a write to a closed pipe would fail and `println!` panic;
    // with the default action the process ends at that write, silently (status: signal 13).
    // One line here covers every print of every subcommand. Only pipes and sockets raise
    // SIGPIPE; outputs are files (written atomically, see `output`) and the link is a tty.
    #[cfg(unix)]
    // SAFETY: setting a signal's disposition to SIG_DFL at the start of main, before any thread
    // exists; no handler is installed.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // SIGINT/SIGTERM/SIGHUP: unfinished outputs' temporary files removed, then the signal's
    // default action (README, "Bad input").
    #[cfg(unix)]
    if let Err(e) = host_tool::output::remove_temporaries_on_signal() {
        eprintln!("driftid: warning: {e:#}");
    }
    cli::common::keep_freed_memory();
    host_tool::pool::start();
    if let Some(bytes) = host_tool::heap::default_budget() {
        host_tool::heap::set_budget(bytes);
    }
    let cli = Cli::parse();
    if let Some(bytes) = cli.max_memory_mib {
        host_tool::heap::set_budget(bytes);
        cli::common::return_freed_memory();
    }
    let result = match &cli.command {
        Command::Demo(a) => cli::demo::run(a),
        Command::Simulate(a) => cli::simulate::run(a),
        Command::Identify(a) => cli::identify::run(a),
        Command::Bench(a) => cli::bench::run(a),
        Command::Diagnose(a) => cli::diagnose::run(a),
        Command::Plan(a) => cli::plan::run(a),
        Command::Report(a) => cli::report::run(a),
        Command::Record(a) => cli::record::run(a),
        Command::Replay(a) => cli::replay::run(a),
    };
    if let Err(e) = result {
        std::process::exit(exit_status(&e));
    }
}

/// Exit status (README, "Exit status"): 0 trusted result, 3 numbers computed but not trusted
/// (printed, with the reasons), 2 usage error or input that cannot support a result.
fn exit_status(e: &anyhow::Error) -> i32 {
    if let Some(u) = e.downcast_ref::<cli::common::Untrusted>() {
        eprintln!("driftid: NOT TRUSTED (exit 3):");
        for r in &u.0 {
            eprintln!("  - {r}");
        }
        return 3;
    }
    eprintln!("driftid: error: {e:#}");
    2
}
