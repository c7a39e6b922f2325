//! `ehactl canbus ...`: CAN bus tools.

use clap::Subcommand;
use ehactl_canopen::hub::Hub;
use std::io::Write;
use std::process::ExitCode;

/// `ehactl canbus` subcommands.
#[derive(Subcommand)]
pub enum CanbusCommand {
    /// socketcand-compatible rawmode hub: relays every frame to every other client, so that
    /// several processes (ehactl, python-can / canopen devices) share one virtual CAN bus.
    /// Prints exactly one line `listening on HOST:PORT` on stdout, then serves until killed.
    Hub {
        /// Address to listen on, HOST:PORT (PORT 0 = pick a free port).
        #[arg(long, default_value = "127.0.0.1:29536")]
        listen: String,
        /// Do not report connects/disconnects on stderr (protocol errors are still reported).
        #[arg(long)]
        quiet: bool,
    },
}

/// Run a `canbus` subcommand.
pub fn run(cmd: CanbusCommand) -> ExitCode {
    match cmd {
        CanbusCommand::Hub { listen, quiet } => {
            let hub = match Hub::bind(&listen, quiet) {
                Ok(h) => h,
                Err(e) => {
                    eprintln!("ehactl: canbus hub --listen {listen}: cannot listen ({e}); expected a free HOST:PORT such as 127.0.0.1:0");
                    return ExitCode::from(2);
                }
            };
            let addr = match hub.local_addr() {
                Ok(a) => a,
                Err(e) => {
                    eprintln!("ehactl: canbus hub: {e}");
                    return ExitCode::from(1);
                }
            };
            let mut out = std::io::stdout().lock();
            let _ = writeln!(out, "listening on {addr}");
            let _ = out.flush();
            drop(out);
            match hub.serve() {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => {
                    eprintln!("ehactl: canbus hub: {e}");
                    ExitCode::from(1)
                }
            }
        }
    }
}
