//! Who is alive and what each client holds: its sessions and environments, counted
//! against [`Limits`] before anything is built.
//!
//! Lock order: this table's lock may be held while taking the engine's session map
//! (committing a session), never the other way round.

use std::collections::{HashMap, HashSet};
use std::sync::{Mutex, MutexGuard};

use crate::limits::{Limits, Usage};
use crate::protocol::{ErrorCode, ErrorReply};

#[derive(Default)]
pub(crate) struct ClientTable(Mutex<HashMap<String, ClientState>>);

#[derive(Default)]
struct ClientState {
    /// The client's liveliness token is declared.
    alive: bool,
    /// Its open sessions.
    sessions: HashSet<String>,
    /// Sessions and environments counted against its limits: the open ones plus those
    /// being built.
    usage: Usage,
}

/// Room taken for a session being built; given back when dropped uncommitted.
pub(crate) struct Reservation<'a> {
    table: &'a ClientTable,
    client: String,
    num_envs: u32,
    committed: bool,
}

impl ClientTable {
    fn lock(&self) -> MutexGuard<'_, HashMap<String, ClientState>> {
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub fn appeared(&self, client: &str) {
        self.lock().entry(client.to_owned()).or_default().alive = true;
    }

    /// Forgets a vanished client; returns its sessions, which the caller closes.
    pub fn vanished(&self, client: &str) -> Vec<String> {
        let mut clients = self.lock();
        let Some(state) = clients.get_mut(client) else {
            return Vec::new();
        };
        state.alive = false;
        let ids: Vec<String> = state.sessions.drain().collect();
        state.usage = Usage::default();
        // Sessions still being built keep their counts until their reservations drop.
        clients.retain(|_, state| state.alive || state.usage != Usage::default());
        ids
    }

    pub fn is_alive(&self, client: &str) -> bool {
        self.lock().get(client).is_some_and(|state| state.alive)
    }

    pub fn usage(&self, client: &str) -> Usage {
        self.lock()
            .get(client)
            .map_or_else(Usage::default, |state| state.usage)
    }

    /// Takes room for a session of `num_envs` environments, or says which limit it
    /// would exceed.
    pub fn reserve(
        &self,
        client: &str,
        num_envs: u32,
        limits: &Limits,
    ) -> Result<Reservation<'_>, ErrorReply> {
        let mut clients = self.lock();
        let usage = &mut clients.entry(client.to_owned()).or_default().usage;
        if usage.sessions >= limits.max_sessions_per_client {
            return Err(ErrorReply::new(
                ErrorCode::LimitExceeded,
                format!(
                    "client `{client}` holds {} sessions, this engine's limit per client; \
                     close one first",
                    usage.sessions
                ),
            ));
        }
        if usage.envs + u64::from(num_envs) > u64::from(limits.max_envs_per_client) {
            return Err(ErrorReply::new(
                ErrorCode::LimitExceeded,
                format!(
                    "client `{client}` holds {} environments; {num_envs} more would exceed \
                     this engine's limit of {} per client",
                    usage.envs, limits.max_envs_per_client
                ),
            ));
        }
        usage.sessions += 1;
        usage.envs += u64::from(num_envs);
        Ok(Reservation {
            table: self,
            client: client.to_owned(),
            num_envs,
            committed: false,
        })
    }

    /// Opens the reserved session: `insert` puts it in the engine's map while this table
    /// is locked, so a client vanishing at the same moment either sees it or refuses it.
    pub fn commit(
        &self,
        mut reservation: Reservation<'_>,
        id: &str,
        insert: impl FnOnce(),
    ) -> Result<(), ErrorReply> {
        {
            let mut clients = self.lock();
            if let Some(state) = clients.get_mut(&reservation.client)
                && state.alive
            {
                state.sessions.insert(id.to_owned());
                insert();
                reservation.committed = true;
                return Ok(());
            }
        }
        // The lock is released: dropping the reservation takes it again.
        Err(ErrorReply::new(
            ErrorCode::NoLiveliness,
            format!("client `{}` vanished during `make`", reservation.client),
        ))
    }

    /// Gives back what a closed session held.
    pub fn release(&self, client: &str, id: &str, num_envs: u32) {
        let mut clients = self.lock();
        if let Some(state) = clients.get_mut(client)
            && state.sessions.remove(id)
        {
            state.usage.sessions -= 1;
            state.usage.envs -= u64::from(num_envs);
        }
    }

    fn unreserve(&self, client: &str, num_envs: u32) {
        let mut clients = self.lock();
        if let Some(state) = clients.get_mut(client) {
            state.usage.sessions = state.usage.sessions.saturating_sub(1);
            state.usage.envs = state.usage.envs.saturating_sub(u64::from(num_envs));
            if !state.alive && state.usage == Usage::default() {
                clients.remove(client);
            }
        }
    }
}

impl Drop for Reservation<'_> {
    fn drop(&mut self) {
        if !self.committed {
            self.table.unreserve(&self.client, self.num_envs);
        }
    }
}
