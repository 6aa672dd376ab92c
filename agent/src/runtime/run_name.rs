//! Run and sweep folder names that a person reads: `<stem>__<UTC start time>`, e.g.
//! `dst__mompo__0__20261125-091122`. Sorted by name they are in start order (what
//! `deploy/k8s/base/agent/train-or-resume.sh` relies on to find the newest run), and
//! each is claimed with an atomic `create_dir`, so two runs started in the same second
//! under the same parent (a sweep, or a script starting runs back to back) get
//! `..-091122` and `..-091122-2` instead of sharing a folder.

use std::io;
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use time::OffsetDateTime;

/// `t` as `YYYYMMDD-HHMMSS` in UTC (times before 1970 read as 1970-01-01 00:00:00).
pub fn utc_stamp(t: SystemTime) -> String {
    let t = OffsetDateTime::from(t.max(UNIX_EPOCH));
    format!(
        "{:04}{:02}{:02}-{:02}{:02}{:02}",
        t.year(),
        u8::from(t.month()),
        t.day(),
        t.hour(),
        t.minute(),
        t.second()
    )
}

/// Make and return `<parent>/<stem>__<utc_stamp(started)>`, or, when that folder exists
/// already, the first free `..-2`, `..-3`, ... (`parent` is made when missing).
pub fn create_run_dir(parent: &Path, stem: &str, started: SystemTime) -> io::Result<PathBuf> {
    std::fs::create_dir_all(parent)?;
    let base = format!("{stem}__{}", utc_stamp(started));
    for n in 1u32.. {
        let name = if n == 1 {
            base.clone()
        } else {
            format!("{base}-{n}")
        };
        let dir = parent.join(name);
        match std::fs::create_dir(&dir) {
            Ok(()) => return Ok(dir),
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    }
    unreachable!("u32 suffixes run out only after 4 billion runs in one second")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn stamps_are_utc_seconds() {
        // datetime.fromtimestamp(1795597828.690, timezone.utc) = 2026-11-25 09:10:28.690.
        let t = UNIX_EPOCH + Duration::from_millis(1_795_597_828_690);
        assert_eq!(utc_stamp(t), "20261125-091028");
        assert_eq!(utc_stamp(UNIX_EPOCH), "19700101-000000");
        assert_eq!(
            utc_stamp(UNIX_EPOCH - Duration::from_secs(1)),
            "19700101-000000"
        );
        // date(2000, 2, 29) - date(1970, 1, 1) = 11 016 days: a leap day of a year divisible by 400.
        let t = UNIX_EPOCH + Duration::from_secs(11_016 * 86_400);
        assert_eq!(utc_stamp(t), "20000229-000000");
        // 23:59:59 on 31 December: the last second before the year changes.
        let t = UNIX_EPOCH + Duration::from_secs(20_819 * 86_400 - 1); // 2027-01-01 is day 20 819
        assert_eq!(utc_stamp(t), "20261231-235959");
    }

    #[test]
    fn runs_started_in_the_same_second_get_their_own_folders_in_start_order() {
        let parent = tempfile::tempdir().unwrap();
        let t = UNIX_EPOCH + Duration::from_millis(1_795_597_828_690);
        let later = t + Duration::from_secs(1);
        let dirs: Vec<PathBuf> = [t, t, t, later]
            .into_iter()
            .map(|s| create_run_dir(&parent.path().join("runs"), "dst__mompo__0", s).unwrap())
            .collect();
        let names: Vec<String> = dirs
            .iter()
            .map(|d| d.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(
            names,
            [
                "dst__mompo__0__20261125-091028",
                "dst__mompo__0__20261125-091028-2",
                "dst__mompo__0__20261125-091028-3",
                "dst__mompo__0__20261125-091029",
            ]
        );
        assert!(dirs.iter().all(|d| d.is_dir()));
        let mut sorted = names.clone();
        sorted.sort();
        assert_eq!(sorted, names, "name order is start order");
    }
}
