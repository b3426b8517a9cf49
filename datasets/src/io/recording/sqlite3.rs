//! rosbag2's sqlite3 storage (`.db3`): a `topics` table (id, name, type,
//! serialization_format) and a `messages` table (topic_id, timestamp in
//! nanoseconds, data).

use std::path::Path;

use rusqlite::{Connection, OpenFlags};

use crate::error::{DataError, Result};
use crate::io::recording::messages::{Encoding, canonical_type};
use crate::io::recording::{RawVisitor, TopicInfo};

fn sql_error(path: &Path, e: rusqlite::Error) -> DataError {
    DataError::invalid(path, format!("not a readable rosbag2 sqlite3 file: {e}"))
}

fn open(path: &Path) -> Result<Connection> {
    if !path.is_file() {
        return Err(DataError::invalid(path, crate::atomic::why_unreadable(path)));
    }
    // Read only, and never create a database where a file is missing.
    Connection::open_with_flags(path, OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX)
        .map_err(|e| sql_error(path, e))
}

fn encoding(path: &Path, topic: &str, format: &str) -> Result<Encoding> {
    match format {
        "cdr" => Ok(Encoding::Cdr),
        other => Err(DataError::invalid(path, format!("topic {topic}: serialization format `{other}` is not cdr"))),
    }
}

/// The topics with their counts and timestamp spans.
pub fn topics(path: &Path) -> Result<Vec<TopicInfo>> {
    let db = open(path)?;
    let mut statement = db
        .prepare(
            "SELECT t.name, t.type, t.serialization_format, COUNT(m.id), MIN(m.timestamp), MAX(m.timestamp) \
             FROM topics t LEFT JOIN messages m ON m.topic_id = t.id GROUP BY t.id ORDER BY t.name",
        )
        .map_err(|e| sql_error(path, e))?;
    let rows = statement
        .query_map([], |row| {
            Ok((
                row.get::<_, String>(0)?,
                row.get::<_, String>(1)?,
                row.get::<_, String>(2)?,
                row.get::<_, i64>(3)?,
                row.get::<_, Option<i64>>(4)?,
                row.get::<_, Option<i64>>(5)?,
            ))
        })
        .map_err(|e| sql_error(path, e))?;
    // A message that names no topic would be dropped by every join: a damaged bag, said once here.
    let orphans: i64 = db
        .query_row(
            "SELECT COUNT(*) FROM messages WHERE topic_id IS NULL OR topic_id NOT IN (SELECT id FROM topics)",
            [],
            |row| row.get(0),
        )
        .map_err(|e| sql_error(path, e))?;
    if orphans > 0 {
        return Err(DataError::invalid(
            path,
            format!("{orphans} messages have a topic_id that is NULL or names no row of `topics`: a damaged bag"),
        ));
    }
    let mut out = Vec::new();
    for row in rows {
        let (name, type_name, format, count, first_ns, last_ns) = row.map_err(|e| sql_error(path, e))?;
        out.push(TopicInfo {
            encoding: encoding(path, &name, &format)?,
            type_name: canonical_type(&type_name),
            name,
            count: count.max(0) as u64,
            first_ns,
            last_ns,
        });
    }
    Ok(out)
}

/// Visits every message in timestamp order (rosbag2 replays them so).
pub fn visit(path: &Path, visit: &mut RawVisitor<'_>) -> Result<()> {
    let db = open(path)?;
    let mut statement = db
        .prepare(
            "SELECT t.name, m.timestamp, m.data FROM messages m JOIN topics t ON m.topic_id = t.id \
             ORDER BY m.timestamp, m.id",
        )
        .map_err(|e| sql_error(path, e))?;
    let mut rows = statement.query([]).map_err(|e| sql_error(path, e))?;
    while let Some(row) = rows.next().map_err(|e| sql_error(path, e))? {
        let topic: String = row.get(0).map_err(|e| sql_error(path, e))?;
        let stamp: i64 = row.get(1).map_err(|e| sql_error(path, e))?;
        let data = row.get_ref(2).map_err(|e| sql_error(path, e))?;
        let bytes =
            data.as_blob().map_err(|e| DataError::invalid(path, format!("topic {topic}: message data: {e}")))?;
        visit(&topic, stamp, bytes)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_naming_no_topic_are_an_error_not_dropped() {
        let source =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/recordings/rosbag2_sqlite3/rosbag2_sqlite3.db3");
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bag.db3");
        std::fs::copy(&source, &path).unwrap();
        let before: u64 = topics(&path).unwrap().iter().map(|t| t.count).sum();
        assert!(before > 0);
        // rosbag2's schema keeps topic_id NOT NULL; an id with no topic row is what damage leaves.
        let db = Connection::open(&path).unwrap();
        db.execute("INSERT INTO messages (topic_id, timestamp, data) VALUES (999, 5, x'00')", []).unwrap();
        drop(db);
        let error = topics(&path).unwrap_err().to_string();
        assert!(error.contains("bag.db3") && error.contains("1 messages have a topic_id"), "{error}");
    }
}
