//! Exclusive control of axes: leases with a time to live.
//!
//! A client acquires a set of axes (all or none) and gets a token; the lease
//! lapses `ttl` after its latest renewal. The table is pure: time comes in
//! as an argument and [`LeaseTable::expire`] returns what lapsed, so the
//! runtime decides what to stop.
//!
//! With authentication on, a lease is bound to the identity that acquired
//! it ([`LeaseTable::bind_owner`]): the token alone is not the control,
//! so a token seen by another identity (a shared screen, a log) does not
//! let that identity command the axes ([`LeaseTable::check_owner`]).

use std::collections::BTreeMap;
use std::time::Duration;

/// A granted lease.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Lease {
    /// The secret token commands carry.
    pub token: String,
    /// Who holds it, as shown to others.
    pub holder: String,
    /// The axes, in acquisition order.
    pub axes: Vec<String>,
    /// Time to live after each renewal.
    pub ttl: Duration,
    /// When it lapses unless renewed.
    pub expires: Duration,
}

/// Why a lease operation was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LeaseError {
    /// Another lease holds the axis.
    #[error("axis {axis} is controlled by {holder}")]
    Held {
        /// The axis.
        axis: String,
        /// Its holder.
        holder: String,
    },
    /// The command carried no lease although one is needed.
    #[error("axis {axis} needs control: call AcquireControl first and pass the lease")]
    NoLease {
        /// The axis.
        axis: String,
    },
    /// The token is unknown (never granted, released, or lapsed).
    #[error("unknown or lapsed lease")]
    Unknown,
    /// The lease does not cover the axis (nobody controls it).
    #[error("the lease does not cover axis {axis}")]
    NotCovered {
        /// The axis.
        axis: String,
    },
    /// The lease was acquired by another identity.
    #[error(
        "the lease belongs to {owner}, not to {caller}: a lease is bound to the identity that \
         acquired it"
    )]
    OtherIdentity {
        /// The identity the lease is bound to.
        owner: String,
        /// The identity that presented it.
        caller: String,
    },
}

/// All leases of a gateway.
#[derive(Debug, Default)]
pub struct LeaseTable {
    leases: BTreeMap<String, Lease>,
    /// axis → token of the lease holding it.
    holders: BTreeMap<String, String>,
    /// token → the identity the lease is bound to (leases of callers
    /// without an identity are not bound).
    owners: BTreeMap<String, String>,
}

impl LeaseTable {
    /// An empty table.
    pub fn new() -> Self {
        Self::default()
    }

    /// Grants `axes` to `holder` under `token` (the caller makes it
    /// unguessable), all or none.
    ///
    /// # Errors
    /// [`LeaseError::Held`] naming the first axis held by another lease.
    pub fn acquire(
        &mut self,
        token: String,
        holder: String,
        axes: Vec<String>,
        ttl: Duration,
        now: Duration,
    ) -> Result<Lease, LeaseError> {
        for axis in &axes {
            if let Some(t) = self.holders.get(axis) {
                return Err(LeaseError::Held {
                    axis: axis.clone(),
                    holder: self.leases[t].holder.clone(),
                });
            }
        }
        for axis in &axes {
            self.holders.insert(axis.clone(), token.clone());
        }
        let lease = Lease {
            token: token.clone(),
            holder,
            axes,
            ttl,
            expires: now + ttl,
        };
        self.leases.insert(token, lease.clone());
        Ok(lease)
    }

    /// Extends a lease by its TTL from `now`.
    ///
    /// # Errors
    /// [`LeaseError::Unknown`].
    pub fn renew(&mut self, token: &str, now: Duration) -> Result<Lease, LeaseError> {
        let lease = self.leases.get_mut(token).ok_or(LeaseError::Unknown)?;
        lease.expires = now + lease.ttl;
        Ok(lease.clone())
    }

    /// Binds a lease to the identity that acquired it; from then on only
    /// that identity passes [`LeaseTable::check_owner`].
    ///
    /// # Errors
    /// [`LeaseError::Unknown`].
    pub fn bind_owner(&mut self, token: &str, owner: String) -> Result<(), LeaseError> {
        if !self.leases.contains_key(token) {
            return Err(LeaseError::Unknown);
        }
        self.owners.insert(token.to_string(), owner);
        Ok(())
    }

    /// The identity a lease is bound to, if any.
    pub fn owner_of(&self, token: &str) -> Option<&str> {
        self.owners.get(token).map(String::as_str)
    }

    /// Checks that `caller` may present `token`: the lease is unbound, or
    /// bound to `caller`. An unknown token passes here (the lease check
    /// itself says it is unknown).
    ///
    /// # Errors
    /// [`LeaseError::OtherIdentity`].
    pub fn check_owner(&self, token: &str, caller: Option<&str>) -> Result<(), LeaseError> {
        match (self.owners.get(token), caller) {
            (Some(owner), Some(c)) if owner == c => Ok(()),
            (Some(owner), c) => Err(LeaseError::OtherIdentity {
                owner: owner.clone(),
                caller: c.unwrap_or("an unauthenticated caller").to_string(),
            }),
            (None, _) => Ok(()),
        }
    }

    /// Ends a lease.
    ///
    /// # Errors
    /// [`LeaseError::Unknown`].
    pub fn release(&mut self, token: &str) -> Result<Lease, LeaseError> {
        let lease = self.leases.remove(token).ok_or(LeaseError::Unknown)?;
        self.owners.remove(token);
        for axis in &lease.axes {
            self.holders.remove(axis);
        }
        Ok(lease)
    }

    /// Removes and returns every lease that lapsed at `now`.
    pub fn expire(&mut self, now: Duration) -> Vec<Lease> {
        let lapsed: Vec<String> = self
            .leases
            .values()
            .filter(|l| l.expires <= now)
            .map(|l| l.token.clone())
            .collect();
        lapsed.iter().filter_map(|t| self.release(t).ok()).collect()
    }

    /// The earliest expiry, to schedule the next [`LeaseTable::expire`].
    pub fn next_expiry(&self) -> Option<Duration> {
        self.leases.values().map(|l| l.expires).min()
    }

    /// The lease holding `axis`, if any.
    pub fn holder_of(&self, axis: &str) -> Option<&Lease> {
        self.holders.get(axis).map(|t| &self.leases[t])
    }

    /// Checks that `token` controls `axis`, and renews it.
    ///
    /// # Errors
    /// [`LeaseError::Held`] when someone else holds the axis,
    /// [`LeaseError::NoLease`] without a token, [`LeaseError::Unknown`] for a
    /// lapsed or invented token, [`LeaseError::NotCovered`] when the lease
    /// is valid but is not for this axis.
    pub fn authorize(
        &mut self,
        axis: &str,
        token: Option<&str>,
        now: Duration,
    ) -> Result<(), LeaseError> {
        let held_by = self.holders.get(axis).cloned();
        match (held_by, token) {
            (Some(h), Some(t)) if h == t => {
                self.renew(t, now)?;
                Ok(())
            }
            (Some(h), _) => Err(LeaseError::Held {
                axis: axis.to_string(),
                holder: self.leases[&h].holder.clone(),
            }),
            (None, None) => Err(LeaseError::NoLease {
                axis: axis.to_string(),
            }),
            (None, Some(t)) => {
                if self.leases.contains_key(t) {
                    Err(LeaseError::NotCovered {
                        axis: axis.to_string(),
                    })
                } else {
                    Err(LeaseError::Unknown)
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    fn axes(names: &[&str]) -> Vec<String> {
        names.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn acquire_is_all_or_none_and_names_the_holder() {
        let mut t = LeaseTable::new();
        t.acquire(
            "a".into(),
            "hmi1".into(),
            axes(&["X", "Y"]),
            100 * MS,
            Duration::ZERO,
        )
        .unwrap();
        let err = t
            .acquire(
                "b".into(),
                "hmi2".into(),
                axes(&["Z", "Y"]),
                100 * MS,
                Duration::ZERO,
            )
            .unwrap_err();
        assert_eq!(
            err,
            LeaseError::Held {
                axis: "Y".into(),
                holder: "hmi1".into()
            }
        );
        assert_eq!(err.to_string(), "axis Y is controlled by hmi1");
        // Z was not taken by the refused request.
        assert!(t.holder_of("Z").is_none());
        t.acquire(
            "c".into(),
            "hmi2".into(),
            axes(&["Z"]),
            100 * MS,
            Duration::ZERO,
        )
        .unwrap();
    }

    #[test]
    fn authorize_covers_every_case() {
        let mut t = LeaseTable::new();
        t.acquire(
            "a".into(),
            "hmi1".into(),
            axes(&["X"]),
            100 * MS,
            Duration::ZERO,
        )
        .unwrap();
        t.acquire(
            "b".into(),
            "hmi2".into(),
            axes(&["Y"]),
            100 * MS,
            Duration::ZERO,
        )
        .unwrap();
        assert_eq!(t.authorize("X", Some("a"), 50 * MS), Ok(()));
        assert!(matches!(
            t.authorize("X", Some("b"), 50 * MS),
            Err(LeaseError::Held { .. })
        ));
        assert!(matches!(
            t.authorize("X", None, 50 * MS),
            Err(LeaseError::Held { .. })
        ));
        assert_eq!(
            t.authorize("Z", None, 50 * MS),
            Err(LeaseError::NoLease { axis: "Z".into() })
        );
        assert_eq!(
            t.authorize("Z", Some("a"), 50 * MS),
            Err(LeaseError::NotCovered { axis: "Z".into() })
        );
        assert_eq!(
            t.authorize("Z", Some("nope"), 50 * MS),
            Err(LeaseError::Unknown)
        );
    }

    #[test]
    fn leases_lapse_ttl_after_the_latest_renewal() {
        let mut t = LeaseTable::new();
        t.acquire(
            "a".into(),
            "hmi1".into(),
            axes(&["X"]),
            100 * MS,
            Duration::ZERO,
        )
        .unwrap();
        t.acquire(
            "b".into(),
            "hmi2".into(),
            axes(&["Y"]),
            100 * MS,
            Duration::ZERO,
        )
        .unwrap();
        // A command carrying the lease renews it.
        t.authorize("X", Some("a"), 60 * MS).unwrap();
        assert_eq!(t.next_expiry(), Some(100 * MS));
        assert!(t.expire(99 * MS).is_empty());
        let lapsed = t.expire(100 * MS);
        assert_eq!(lapsed.len(), 1);
        assert_eq!(lapsed[0].axes, axes(&["Y"]));
        assert!(t.holder_of("Y").is_none());
        assert_eq!(t.next_expiry(), Some(160 * MS));
        assert_eq!(t.expire(160 * MS)[0].token, "a");
        assert_eq!(t.renew("a", 200 * MS), Err(LeaseError::Unknown));
    }

    #[test]
    fn a_bound_lease_serves_only_its_identity() {
        let mut t = LeaseTable::new();
        t.acquire(
            "a".into(),
            "panel (operator-1@10.0.0.5:1)".into(),
            axes(&["X"]),
            100 * MS,
            Duration::ZERO,
        )
        .unwrap();
        // Unbound: anyone holding the token passes.
        assert_eq!(t.check_owner("a", Some("token engineer-1")), Ok(()));
        t.bind_owner("a", "token operator-1".into()).unwrap();
        assert_eq!(t.owner_of("a"), Some("token operator-1"));
        assert_eq!(t.check_owner("a", Some("token operator-1")), Ok(()));
        let e = t.check_owner("a", Some("token engineer-1")).unwrap_err();
        assert_eq!(
            e,
            LeaseError::OtherIdentity {
                owner: "token operator-1".into(),
                caller: "token engineer-1".into()
            }
        );
        assert!(e.to_string().contains("bound to the identity"), "{e}");
        assert!(t.check_owner("a", None).is_err());
        assert_eq!(t.bind_owner("zz", "x".into()), Err(LeaseError::Unknown));
        // A released (or lapsed) lease forgets its owner.
        t.release("a").unwrap();
        assert_eq!(t.owner_of("a"), None);
        t.acquire(
            "b".into(),
            "h".into(),
            axes(&["X"]),
            100 * MS,
            Duration::ZERO,
        )
        .unwrap();
        t.bind_owner("b", "o".into()).unwrap();
        t.expire(100 * MS);
        assert_eq!(t.owner_of("b"), None);
    }

    #[test]
    fn release_frees_the_axes() {
        let mut t = LeaseTable::new();
        t.acquire(
            "a".into(),
            "hmi1".into(),
            axes(&["X", "Y"]),
            100 * MS,
            Duration::ZERO,
        )
        .unwrap();
        assert_eq!(t.release("a").unwrap().axes, axes(&["X", "Y"]));
        assert_eq!(t.release("a"), Err(LeaseError::Unknown));
        t.acquire(
            "b".into(),
            "hmi2".into(),
            axes(&["X"]),
            100 * MS,
            Duration::ZERO,
        )
        .unwrap();
    }
}
