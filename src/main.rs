//! The `flatport` command line. All geometry lives in the library; this binary parses arguments,
//! reads and writes files, and reports.

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
