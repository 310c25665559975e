//! `choreo token`: lines for a token file (`choreo serve --tokens FILE`).

use anyhow::{bail, Result};
use choreo::service::auth::hash_token;
use rand::RngCore;
use std::io::Read;

#[derive(clap::Subcommand)]
pub enum TokenCmd {
    /// A new random token: prints the secret (give it to the client, once)
    /// on stderr and the token file's line (name, scopes, hash) on stdout.
    New {
        name: String,
        /// Comma-separated: read, write, admin.
        #[arg(long, default_value = "read")]
        scopes: String,
    },
    /// The token file's hash of a secret read from standard input.
    Hash,
}

pub fn run(cmd: TokenCmd) -> Result<()> {
    match cmd {
        TokenCmd::New { name, scopes } => {
            let mut bytes = [0u8; 32];
            rand::rngs::OsRng.fill_bytes(&mut bytes);
            let secret: String = bytes.iter().map(|b| format!("{b:02x}")).collect();
            let line = format!("{name} {scopes} {}", hash_token(&secret));
            // Checked as the server will read it.
            choreo::service::auth::parse_tokens("the new line", &line)
                .map_err(anyhow::Error::msg)?;
            eprintln!("token for {name} (shown once): {secret}");
            println!("{line}");
            Ok(())
        }
        TokenCmd::Hash => {
            let mut s = String::new();
            std::io::stdin().read_to_string(&mut s)?;
            let secret = s.trim_end_matches(['\n', '\r']);
            if secret.is_empty() {
                bail!("no secret on standard input");
            }
            println!("{}", hash_token(secret));
            Ok(())
        }
    }
}
