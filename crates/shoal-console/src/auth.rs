//! Operator logins, roles and API tokens (`[console.auth]`).
//!
//! - Three roles, each including the one below: `viewer` (sees everything), `operator`
//!   (also dispatches and aborts missions and tasks, acknowledges events, subscribes to
//!   environment data), `admin` (also manages rules, vehicles, users and tokens).
//! - People log in with a name and password (`POST /api/auth/login`) and get a session in
//!   an `HttpOnly`, `SameSite=Strict` cookie; tools send `Authorization: Bearer <token>`.
//! - Users and tokens live in a JSON file (`users_path`): passwords as Argon2id PHC
//!   strings, tokens and session ids only as SHA-256 digests. The first start with auth
//!   enabled and no admin creates user `admin` and an admin token and logs both once.
//! - Missing or invalid credentials give 401, the wrong role 403, both as `{"error": ...}`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, MutexGuard};

use argon2::Argon2;
use argon2::password_hash::{PasswordHash, PasswordHasher, PasswordVerifier, SaltString};
use axum::http::{HeaderMap, Method, header};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

/// Name of the session cookie.
pub const COOKIE: &str = "shoal_session";

/// What a user or token may do; each role includes the ones before it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Reads everything, changes nothing.
    Viewer,
    /// Also plans, starts and aborts missions and tasks, acknowledges events.
    Operator,
    /// Also manages rules, vehicles, users and tokens.
    Admin,
}

impl std::fmt::Display for Role {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Viewer => "viewer",
            Self::Operator => "operator",
            Self::Admin => "admin",
        })
    }
}

/// The `[console.auth]` section of Shoal's configuration.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AuthConfig {
    /// Require a login or token for the API and the live feed. Off by default: the console
    /// listens on loopback only unless `console.listen` says otherwise.
    pub enabled: bool,
    /// Users and API tokens (hashes only), managed through `/api/auth/users` and
    /// `/api/auth/tokens`; created on the first start with `enabled = true`.
    pub users_path: PathBuf,
    /// How long a login lasts, seconds.
    pub session_ttl_s: u64,
}

impl Default for AuthConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            users_path: PathBuf::from("shoal-data/console-users.json"),
            session_ttl_s: 12 * 3600,
        }
    }
}

/// Why the authentication store cannot be used or changed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AuthError {
    /// The users file cannot be read or written.
    #[error("users file {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What failed.
        source: std::io::Error,
    },
    /// The users file is not valid JSON of the expected shape.
    #[error("users file {path}: {source}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        source: serde_json::Error,
    },
    /// The operating system's random source failed.
    #[error("no randomness for salts and tokens: {0}")]
    Random(String),
    /// Hashing failed (should not happen with valid parameters).
    #[error("password hashing failed: {0}")]
    Hash(String),
    /// A request to change users or tokens is wrong; the text says how.
    #[error("{0}")]
    Invalid(String),
    /// No such user or token.
    #[error("{0}")]
    NotFound(String),
    /// Authentication is switched off, so there is nothing to manage.
    #[error("authentication is disabled ([console.auth] enabled = false)")]
    Disabled,
    /// The name and password do not match (deliberately not saying which).
    #[error("wrong user name or password")]
    BadCredentials,
}

/// Who made a request.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Identity {
    /// User name, or the token's name.
    pub name: String,
    /// What they may do.
    pub role: Role,
    /// `session`, `token`, or `open` when authentication is disabled.
    pub via: &'static str,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct UserRecord {
    name: String,
    role: Role,
    /// Argon2id PHC string (salt and parameters included).
    password_hash: String,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TokenRecord {
    id: String,
    name: String,
    role: Role,
    /// Hex SHA-256 of the token: tokens are long random strings, so a fast hash suffices.
    sha256: String,
    created_ms: i64,
}

#[derive(Debug, Default, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct UsersFile {
    users: Vec<UserRecord>,
    tokens: Vec<TokenRecord>,
}

/// A user as the API lists it (no hash).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct UserInfo {
    /// Login name.
    pub name: String,
    /// Role.
    pub role: Role,
}

/// A token as the API lists it (never the token itself).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct TokenInfo {
    /// Identifier, for deleting it.
    pub id: String,
    /// The tool it is for.
    pub name: String,
    /// Role.
    pub role: Role,
    /// When it was made, ms since the Unix epoch.
    pub created_ms: i64,
}

/// Credentials made on the first start, shown once in the log.
#[derive(Debug, Clone)]
pub struct Bootstrap {
    /// The admin's login name.
    pub user: String,
    /// The admin's password.
    pub password: String,
    /// An admin API token.
    pub token: String,
}

#[derive(Debug)]
struct Session {
    identity: Identity,
    expires_ms: i64,
}

#[derive(Debug, Default)]
struct Inner {
    file: UsersFile,
    /// SHA-256 of the session id -> session; sessions end with the process.
    sessions: HashMap<String, Session>,
}

/// The authentication store: users, tokens and live sessions.
#[derive(Debug)]
pub struct Auth {
    enabled: bool,
    path: PathBuf,
    ttl_ms: i64,
    inner: Mutex<Inner>,
    /// A real Argon2 hash checked when the user does not exist, so an unknown user and a
    /// wrong password take equally long (no user enumeration by timing).
    decoy_hash: String,
}

fn now_ms() -> i64 {
    shoal_model::now_ms()
}

fn random_hex(bytes: usize) -> Result<String, AuthError> {
    let mut buf = vec![0u8; bytes];
    getrandom::fill(&mut buf).map_err(|e| AuthError::Random(e.to_string()))?;
    Ok(hex::encode(buf))
}

fn sha256_hex(secret: &str) -> String {
    hex::encode(Sha256::digest(secret.as_bytes()))
}

/// An Argon2id PHC string for `password` with a fresh random salt.
pub fn hash_password(password: &str) -> Result<String, AuthError> {
    let mut salt = [0u8; 16];
    getrandom::fill(&mut salt).map_err(|e| AuthError::Random(e.to_string()))?;
    let salt = SaltString::encode_b64(&salt).map_err(|e| AuthError::Hash(e.to_string()))?;
    Argon2::default()
        .hash_password(password.as_bytes(), &salt)
        .map(|h| h.to_string())
        .map_err(|e| AuthError::Hash(e.to_string()))
}

fn verify_password(password: &str, phc: &str) -> bool {
    PasswordHash::new(phc).is_ok_and(|h| {
        Argon2::default()
            .verify_password(password.as_bytes(), &h)
            .is_ok()
    })
}

fn check_name(what: &str, name: &str) -> Result<(), AuthError> {
    let ok = (1..=32).contains(&name.len())
        && name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'.' | b'-'));
    if ok {
        Ok(())
    } else {
        Err(AuthError::Invalid(format!(
            "{what}: 1 to 32 letters, digits, '_', '.' or '-'"
        )))
    }
}

/// Least password length for users made through the API.
pub const MIN_PASSWORD_LEN: usize = 10;

impl Auth {
    /// No authentication: every request is allowed, as an `open` admin.
    pub fn disabled() -> Self {
        Self {
            enabled: false,
            path: PathBuf::new(),
            ttl_ms: 0,
            inner: Mutex::new(Inner::default()),
            decoy_hash: String::new(),
        }
    }

    /// Opens the store for `config`; with auth enabled and no admin yet, creates one and
    /// returns its credentials (to be shown once).
    pub fn load(config: &AuthConfig) -> Result<(Self, Option<Bootstrap>), AuthError> {
        if !config.enabled {
            return Ok((Self::disabled(), None));
        }
        let path = config.users_path.clone();
        let file = match std::fs::read(&path) {
            Ok(bytes) => serde_json::from_slice(&bytes).map_err(|source| AuthError::Parse {
                path: path.clone(),
                source,
            })?,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => UsersFile::default(),
            Err(source) => return Err(AuthError::Io { path, source }),
        };
        let ttl_ms = i64::try_from(config.session_ttl_s.saturating_mul(1000)).unwrap_or(i64::MAX);
        let auth = Self {
            enabled: true,
            path,
            ttl_ms,
            inner: Mutex::new(Inner {
                file,
                sessions: HashMap::new(),
            }),
            decoy_hash: hash_password("not a password anyone has")?,
        };
        let has_admin = auth.lock().file.users.iter().any(|u| u.role == Role::Admin);
        if has_admin {
            return Ok((auth, None));
        }
        let password = random_hex(12)?;
        auth.set_user("admin", &password, Role::Admin)?;
        let (_, token) = auth.create_token("bootstrap", Role::Admin)?;
        let boot = Bootstrap {
            user: "admin".into(),
            password,
            token,
        };
        Ok((auth, Some(boot)))
    }

    /// True when requests must carry credentials.
    pub fn enabled(&self) -> bool {
        self.enabled
    }

    /// Where users and tokens are kept.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Session lifetime, seconds (for the cookie's Max-Age).
    pub fn ttl_s(&self) -> i64 {
        self.ttl_ms / 1000
    }

    fn lock(&self) -> MutexGuard<'_, Inner> {
        self.inner
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    fn save(&self, file: &UsersFile) -> Result<(), AuthError> {
        let io = |source| AuthError::Io {
            path: self.path.clone(),
            source,
        };
        if let Some(dir) = self.path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(io)?;
        }
        let json = serde_json::to_vec_pretty(file).map_err(|source| AuthError::Parse {
            path: self.path.clone(),
            source,
        })?;
        // Written aside and renamed, so a crash leaves the old file or the new one.
        let tmp = self.path.with_extension("json.tmp");
        std::fs::write(&tmp, json).map_err(io)?;
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&tmp, std::fs::Permissions::from_mode(0o600)).map_err(io)?;
        }
        std::fs::rename(&tmp, &self.path).map_err(io)
    }

    /// Who sent these headers: a bearer token, else the session cookie.
    /// The error is the reason to give with 401.
    pub fn authenticate(&self, headers: &HeaderMap) -> Result<Identity, &'static str> {
        if !self.enabled {
            return Ok(Identity {
                name: "operator".into(),
                role: Role::Admin,
                via: "open",
            });
        }
        if let Some(value) = headers.get(header::AUTHORIZATION) {
            let token = value
                .to_str()
                .ok()
                .and_then(|v| v.strip_prefix("Bearer "))
                .map(str::trim)
                .ok_or("the Authorization header must be `Bearer <token>`")?;
            let digest = sha256_hex(token);
            let inner = self.lock();
            return inner
                .file
                .tokens
                .iter()
                .find(|t| t.sha256 == digest)
                .map(|t| Identity {
                    name: t.name.clone(),
                    role: t.role,
                    via: "token",
                })
                .ok_or("unknown or revoked API token");
        }
        let session = session_cookie(headers).ok_or("log in first (no session cookie or token)")?;
        let digest = sha256_hex(session);
        let mut inner = self.lock();
        let now = now_ms();
        match inner.sessions.get(&digest) {
            Some(s) if s.expires_ms > now => Ok(s.identity.clone()),
            Some(_) => {
                inner.sessions.remove(&digest);
                Err("the session expired: log in again")
            }
            None => Err("the session ended (logged out or the station restarted): log in again"),
        }
    }

    /// Checks a password and opens a session; returns the session id for the cookie.
    /// Slow on purpose (Argon2): call it off the async threads.
    pub fn login(&self, user: &str, password: &str) -> Result<(String, Identity), AuthError> {
        if !self.enabled {
            return Err(AuthError::Disabled);
        }
        let found = self
            .lock()
            .file
            .users
            .iter()
            .find(|u| u.name == user)
            .cloned();
        let Some(found) = found else {
            verify_password(password, &self.decoy_hash);
            return Err(AuthError::BadCredentials);
        };
        if !verify_password(password, &found.password_hash) {
            return Err(AuthError::BadCredentials);
        }
        let id = random_hex(32)?;
        let identity = Identity {
            name: found.name,
            role: found.role,
            via: "session",
        };
        let now = now_ms();
        let mut inner = self.lock();
        inner.sessions.retain(|_, s| s.expires_ms > now);
        inner.sessions.insert(
            sha256_hex(&id),
            Session {
                identity: identity.clone(),
                expires_ms: now.saturating_add(self.ttl_ms),
            },
        );
        Ok((id, identity))
    }

    /// Ends the session these headers carry, if any.
    pub fn logout(&self, headers: &HeaderMap) {
        if let Some(s) = session_cookie(headers) {
            self.lock().sessions.remove(&sha256_hex(s));
        }
    }

    /// Every user, without hashes.
    pub fn users(&self) -> Vec<UserInfo> {
        self.lock()
            .file
            .users
            .iter()
            .map(|u| UserInfo {
                name: u.name.clone(),
                role: u.role,
            })
            .collect()
    }

    /// Creates a user or replaces its password and role; its sessions end.
    pub fn set_user(&self, name: &str, password: &str, role: Role) -> Result<(), AuthError> {
        if !self.enabled {
            return Err(AuthError::Disabled);
        }
        check_name("name", name)?;
        if password.chars().count() < MIN_PASSWORD_LEN {
            return Err(AuthError::Invalid(format!(
                "password: at least {MIN_PASSWORD_LEN} characters"
            )));
        }
        let hash = hash_password(password)?;
        let mut inner = self.lock();
        let mut file = inner.file.clone();
        if role != Role::Admin && would_lose_last_admin(&file, name) {
            return Err(AuthError::Invalid(format!(
                "{name} is the last admin: make another admin first"
            )));
        }
        file.users.retain(|u| u.name != name);
        file.users.push(UserRecord {
            name: name.to_owned(),
            role,
            password_hash: hash,
        });
        file.users.sort_by(|a, b| a.name.cmp(&b.name));
        self.save(&file)?;
        inner.file = file;
        inner
            .sessions
            .retain(|_, s| !(s.identity.via == "session" && s.identity.name == name));
        Ok(())
    }

    /// Deletes a user and ends its sessions; the last admin cannot go.
    pub fn delete_user(&self, name: &str) -> Result<(), AuthError> {
        if !self.enabled {
            return Err(AuthError::Disabled);
        }
        let mut inner = self.lock();
        if !inner.file.users.iter().any(|u| u.name == name) {
            return Err(AuthError::NotFound(format!("no user {name:?}")));
        }
        if would_lose_last_admin(&inner.file, name) {
            return Err(AuthError::Invalid(format!(
                "{name} is the last admin: make another admin first"
            )));
        }
        let mut file = inner.file.clone();
        file.users.retain(|u| u.name != name);
        self.save(&file)?;
        inner.file = file;
        inner
            .sessions
            .retain(|_, s| !(s.identity.via == "session" && s.identity.name == name));
        Ok(())
    }

    /// Every API token, without the secret.
    pub fn tokens(&self) -> Vec<TokenInfo> {
        self.lock()
            .file
            .tokens
            .iter()
            .map(|t| TokenInfo {
                id: t.id.clone(),
                name: t.name.clone(),
                role: t.role,
                created_ms: t.created_ms,
            })
            .collect()
    }

    /// Makes an API token for a tool; the token itself is returned only here.
    pub fn create_token(&self, name: &str, role: Role) -> Result<(TokenInfo, String), AuthError> {
        if !self.enabled {
            return Err(AuthError::Disabled);
        }
        check_name("name", name)?;
        let token = format!("shoal_{}", random_hex(32)?);
        let record = TokenRecord {
            id: format!("tok-{}", random_hex(6)?),
            name: name.to_owned(),
            role,
            sha256: sha256_hex(&token),
            created_ms: now_ms(),
        };
        let info = TokenInfo {
            id: record.id.clone(),
            name: record.name.clone(),
            role,
            created_ms: record.created_ms,
        };
        let mut inner = self.lock();
        let mut file = inner.file.clone();
        file.tokens.push(record);
        self.save(&file)?;
        inner.file = file;
        Ok((info, token))
    }

    /// Revokes a token.
    pub fn delete_token(&self, id: &str) -> Result<(), AuthError> {
        if !self.enabled {
            return Err(AuthError::Disabled);
        }
        let mut inner = self.lock();
        let mut file = inner.file.clone();
        let before = file.tokens.len();
        file.tokens.retain(|t| t.id != id);
        if file.tokens.len() == before {
            return Err(AuthError::NotFound(format!("no token {id:?}")));
        }
        self.save(&file)?;
        inner.file = file;
        Ok(())
    }
}

fn would_lose_last_admin(file: &UsersFile, name: &str) -> bool {
    let admins: Vec<&str> = file
        .users
        .iter()
        .filter(|u| u.role == Role::Admin)
        .map(|u| u.name.as_str())
        .collect();
    admins == [name]
}

/// The session id in the request's cookies.
fn session_cookie(headers: &HeaderMap) -> Option<&str> {
    headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|kv| kv.trim().split_once('='))
        .find(|(k, _)| *k == COOKIE)
        .map(|(_, v)| v)
        .filter(|v| !v.is_empty())
}

/// The `Set-Cookie` value that opens (`Some(id)`) or ends (`None`) a session.
pub fn session_set_cookie(id: Option<&str>, max_age_s: i64) -> String {
    match id {
        Some(id) => {
            format!("{COOKIE}={id}; HttpOnly; SameSite=Strict; Path=/; Max-Age={max_age_s}")
        }
        None => format!("{COOKIE}=; HttpOnly; SameSite=Strict; Path=/; Max-Age=0"),
    }
}

/// The least role a request needs, or `None` for what anyone may fetch (the console's
/// files, health, the API description, logging in and out, who am I). `/metrics` is a
/// read like any other: a scraper sends a viewer token.
pub fn required_role(method: &Method, path: &str) -> Option<Role> {
    if path == "/metrics" {
        return Some(Role::Viewer);
    }
    if !path.starts_with("/api/") {
        return None;
    }
    if matches!(
        path,
        "/api/health"
            | "/api/openapi.json"
            | "/api/auth/login"
            | "/api/auth/logout"
            | "/api/auth/session"
    ) {
        return None;
    }
    if path.starts_with("/api/auth/") {
        return Some(Role::Admin);
    }
    let reads = matches!(*method, Method::GET | Method::HEAD | Method::OPTIONS);
    // SPARQL over POST is still a read-only query.
    if reads || path == "/api/sparql" {
        return Some(Role::Viewer);
    }
    if path == "/api/rules" || path.starts_with("/api/rules/") || path == "/api/vehicles" {
        return Some(Role::Admin);
    }
    Some(Role::Operator)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use axum::http::HeaderValue;

    fn store() -> (tempfile::TempDir, Auth, Bootstrap) {
        let dir = tempfile::tempdir().unwrap();
        let config = AuthConfig {
            enabled: true,
            users_path: dir.path().join("users.json"),
            session_ttl_s: 60,
        };
        let (auth, boot) = Auth::load(&config).unwrap();
        (dir, auth, boot.expect("first start makes an admin"))
    }

    fn with(name: header::HeaderName, value: &str) -> HeaderMap {
        let mut h = HeaderMap::new();
        h.insert(name, HeaderValue::from_str(value).unwrap());
        h
    }

    #[test]
    fn roles_follow_the_method_and_path() {
        use Method as M;
        assert_eq!(required_role(&M::GET, "/"), None);
        assert_eq!(required_role(&M::GET, "/assets/index-1.js"), None);
        assert_eq!(required_role(&M::POST, "/api/auth/login"), None);
        assert_eq!(required_role(&M::GET, "/api/fleet"), Some(Role::Viewer));
        assert_eq!(required_role(&M::GET, "/api/ws"), Some(Role::Viewer));
        assert_eq!(required_role(&M::GET, "/metrics"), Some(Role::Viewer));
        assert_eq!(required_role(&M::GET, "/api/health"), None);
        assert_eq!(required_role(&M::POST, "/api/sparql"), Some(Role::Viewer));
        assert_eq!(
            required_role(&M::POST, "/api/missions"),
            Some(Role::Operator)
        );
        assert_eq!(
            required_role(&M::POST, "/api/missions/m1/abort"),
            Some(Role::Operator)
        );
        assert_eq!(required_role(&M::POST, "/api/tasks"), Some(Role::Operator));
        assert_eq!(
            required_role(&M::POST, "/api/abort-all"),
            Some(Role::Operator)
        );
        assert_eq!(required_role(&M::POST, "/api/rules"), Some(Role::Admin));
        assert_eq!(required_role(&M::PATCH, "/api/rules/r1"), Some(Role::Admin));
        assert_eq!(
            required_role(&M::DELETE, "/api/rules/r1"),
            Some(Role::Admin)
        );
        assert_eq!(required_role(&M::POST, "/api/vehicles"), Some(Role::Admin));
        assert_eq!(required_role(&M::GET, "/api/auth/users"), Some(Role::Admin));
        assert!(Role::Viewer < Role::Operator && Role::Operator < Role::Admin);
    }

    #[test]
    fn the_first_start_makes_an_admin_whose_password_and_token_work() {
        let (dir, auth, boot) = store();
        let (session, who) = auth.login(&boot.user, &boot.password).unwrap();
        assert_eq!(who.role, Role::Admin);
        let cookie = with(header::COOKIE, &format!("theme=dark; {COOKIE}={session}"));
        assert_eq!(auth.authenticate(&cookie).unwrap().name, "admin");
        let bearer = with(header::AUTHORIZATION, &format!("Bearer {}", boot.token));
        assert_eq!(auth.authenticate(&bearer).unwrap().via, "token");
        // Only hashes are stored.
        let text = std::fs::read_to_string(dir.path().join("users.json")).unwrap();
        assert!(!text.contains(&boot.password) && !text.contains(&boot.token));
        assert!(text.contains("$argon2id$"));
        // A second start finds the admin and makes nothing.
        let again = Auth::load(&AuthConfig {
            enabled: true,
            users_path: dir.path().join("users.json"),
            session_ttl_s: 60,
        })
        .unwrap();
        assert!(again.1.is_none());
        assert!(again.0.login("admin", &boot.password).is_ok());
    }

    #[test]
    fn wrong_credentials_and_ended_sessions_are_refused() {
        let (_dir, auth, boot) = store();
        assert!(matches!(
            auth.login("admin", "wrong password"),
            Err(AuthError::BadCredentials)
        ));
        assert!(matches!(
            auth.login("nobody", &boot.password),
            Err(AuthError::BadCredentials)
        ));
        assert!(auth.authenticate(&HeaderMap::new()).is_err());
        let forged = with(header::COOKIE, &format!("{COOKIE}=0123"));
        assert!(auth.authenticate(&forged).is_err());
        let bad = with(header::AUTHORIZATION, "Bearer shoal_guess");
        assert!(auth.authenticate(&bad).is_err());
        let (session, _) = auth.login("admin", &boot.password).unwrap();
        let cookie = with(header::COOKIE, &format!("{COOKIE}={session}"));
        auth.logout(&cookie);
        assert!(auth.authenticate(&cookie).is_err());
    }

    #[test]
    fn users_and_tokens_are_managed_and_the_last_admin_stays() {
        let (_dir, auth, boot) = store();
        assert!(matches!(
            auth.set_user("vera", "short", Role::Viewer),
            Err(AuthError::Invalid(_))
        ));
        assert!(matches!(
            auth.set_user("bad name", "long enough pw", Role::Viewer),
            Err(AuthError::Invalid(_))
        ));
        auth.set_user("vera", "long enough pw", Role::Viewer)
            .unwrap();
        let (_, who) = auth.login("vera", "long enough pw").unwrap();
        assert_eq!(who.role, Role::Viewer);
        assert!(matches!(
            auth.delete_user("admin"),
            Err(AuthError::Invalid(_))
        ));
        assert!(matches!(
            auth.set_user("admin", &boot.password, Role::Operator),
            Err(AuthError::Invalid(_))
        ));
        let (info, token) = auth.create_token("ci-tool", Role::Operator).unwrap();
        let bearer = with(header::AUTHORIZATION, &format!("Bearer {token}"));
        assert_eq!(auth.authenticate(&bearer).unwrap().role, Role::Operator);
        auth.delete_token(&info.id).unwrap();
        assert!(auth.authenticate(&bearer).is_err());
        assert!(matches!(
            auth.delete_token(&info.id),
            Err(AuthError::NotFound(_))
        ));
        auth.delete_user("vera").unwrap();
        assert_eq!(auth.users().len(), 1);
    }

    #[test]
    fn disabled_auth_lets_everyone_in_and_manages_nothing() {
        let auth = Auth::disabled();
        assert_eq!(auth.authenticate(&HeaderMap::new()).unwrap().via, "open");
        assert!(matches!(auth.login("a", "b"), Err(AuthError::Disabled)));
        assert!(matches!(
            auth.set_user("a", "long enough pw", Role::Admin),
            Err(AuthError::Disabled)
        ));
    }

    #[test]
    fn the_session_cookie_is_http_only_and_same_site() {
        let c = session_set_cookie(Some("abc"), 60);
        assert!(c.starts_with("shoal_session=abc;"));
        assert!(c.contains("HttpOnly") && c.contains("SameSite=Strict"));
        assert!(session_set_cookie(None, 60).contains("Max-Age=0"));
    }
}
