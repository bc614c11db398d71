//! `docs/protocol.md` against the protocol's one definition (`core/src/link/protocol.rs`,
//! the telemetry layouts and the reason codes): the block between
//! `<!-- generated: protocol -->` and `<!-- end generated -->` must equal what this test
//! renders from the code. `UPDATE_DOCS=1 cargo test -p startrack-host --test
//! link_protocol_doc` rewrites it.

use startrack_core::link::protocol::{self as p, Direction};
use startrack_core::link::telemetry::{
    ATTITUDE_FIELDS, ATTITUDE_LEN, HK_FIELDS, HK_LEN, STAR_FIELDS, event, type_len,
};
use startrack_core::link::{Rejection, UploadRefusal};
use startrack_core::table::AmendError;
use std::fmt::Write;

const BEGIN: &str = "<!-- generated: protocol -->";
const END: &str = "<!-- end generated -->";

fn render() -> String {
    let mut s = String::new();
    s.push_str("### APIDs\n\n| APID | name |\n|---|---|\n");
    for (apid, name) in p::APIDS {
        writeln!(s, "| `{apid:#05x}` | {name} |").unwrap();
    }
    s.push_str("\n### Messages\n\n| message | direction | APID | service | subtype | data (big-endian) |\n|---|---|---|---|---|---|\n");
    for m in p::MESSAGES {
        let dir = match m.direction {
            Direction::Telecommand => "TC",
            Direction::Telemetry => "TM",
        };
        writeln!(
            s,
            "| {} | {dir} | `{:#05x}` | {} | {} | {} |",
            m.name, m.apid, m.kind.service, m.kind.subtype, m.data
        )
        .unwrap();
    }
    s.push_str("\n### Parameters of set-params\n\n| id | parameter | value |\n|---|---|---|\n");
    for q in p::PARAMS {
        writeln!(s, "| {} | `{}` | {} |", q.id, q.name, q.encoding).unwrap();
    }
    s.push_str("\n### Rejection reasons (TM[1,2] and the anomaly event)\n\n| code | reason | parameter |\n|---|---|---|\n");
    let params = [
        "0",
        "0",
        "the APID",
        "service << 8 \\| subtype",
        "0",
        "0",
        "0",
        "0",
        "refusal << 16 \\| low 16 bits of the expected offset",
        "0",
        "0",
        "the defect commit's error (below)",
        "the P-field received",
    ];
    for (code, param) in (1u16..).zip(params) {
        writeln!(s, "| {code} | {} | {param} |", Rejection::name_of(code)).unwrap();
    }
    s.push_str("\n### Table-upload refusals\n\n| refusal | meaning |\n|---|---|\n");
    for r in [
        UploadRefusal::NotStarted,
        UploadRefusal::Busy,
        UploadRefusal::UnknownKind,
        UploadRefusal::TooLong,
        UploadRefusal::OutOfOrder { expected: 0 },
        UploadRefusal::Incomplete,
        UploadRefusal::CrcMismatch,
        UploadRefusal::Invalid,
        UploadRefusal::Storage,
    ] {
        writeln!(s, "| {} | {} |", r.code(), r.name()).unwrap();
    }
    s.push_str("\n### Defect-commit errors (rejection 12)\n\n| error | meaning |\n|---|---|\n");
    for (e, meaning) in [
        (
            AmendError::NothingToAdd,
            "every confirmed pixel is listed already, or none is confirmed",
        ),
        (AmendError::Read, "the table in force could not be read"),
        (
            AmendError::BadTable,
            "the table in force is not one the core reads",
        ),
        (
            AmendError::DirectoryFull,
            "no room in the directory for a new hot or telegraph section",
        ),
        (AmendError::TooLong, "the new table would pass 4 GiB"),
    ] {
        writeln!(s, "| {} | {meaning} |", e.code()).unwrap();
    }
    s.push_str(
        "\n### Events (TM[5,1] informative, TM[5,2] anomaly)\n\n| event | data |\n|---|---|\n",
    );
    for (id, data) in [
        (
            event::MODE_CHANGE,
            "frame u32, from u8, to u8, reason u8 (0 start, 1 command, 2 acquired, 3 too few stars, 4 reacquire, 5 no table, 6 table available, 7 predicted: the attitude stage predicted the frame's stars)",
        ),
        (event::TABLE_CHANGED, "frame u32, length u32 (0: none)"),
        (event::CONFIG_APPLIED, "frame u32"),
        (
            event::COMMAND_REJECTED,
            "request id u32, reason u16, parameter u32 (anomaly)",
        ),
        (
            event::TABLE_ACCEPTED,
            "kind u8, length u32, CRC-32 u32, sequence u32",
        ),
        (event::TABLE_REFUSED, "kind u8, refusal u16 (anomaly)"),
        (
            event::DEFECTS_COMMITTED,
            "hot pixels added u16, telegraph pixels added u16, length u32, CRC-32 u32, sequence u32",
        ),
    ] {
        writeln!(s, "| {id} | {data} |").unwrap();
    }
    writeln!(
        s,
        "\n### Housekeeping report TM[3,25] ({HK_LEN} bytes)\n\n| field | type | meaning |\n|---|---|---|"
    )
    .unwrap();
    for (name, ty, meaning) in HK_FIELDS {
        writeln!(s, "| `{name}` | {ty} | {meaning} |").unwrap();
    }
    writeln!(
        s,
        "\n### One star of TM[131,2] ({} bytes)\n\n| field | type | meaning |\n|---|---|---|",
        p::STAR_BYTES
    )
    .unwrap();
    for (name, ty, meaning) in STAR_FIELDS {
        writeln!(s, "| `{name}` | {ty} | {meaning} |").unwrap();
    }
    writeln!(
        s,
        "\n### Attitude report TM[134,2] ({ATTITUDE_LEN} bytes)\n\n| field | type | meaning |\n|---|---|---|"
    )
    .unwrap();
    for (name, ty, meaning) in ATTITUDE_FIELDS {
        writeln!(s, "| `{name}` | {ty} | {meaning} |").unwrap();
    }
    s
}

#[test]
fn layouts_add_up() {
    let star: usize = STAR_FIELDS.iter().map(|f| type_len(f.1)).sum();
    assert_eq!(star, p::STAR_BYTES);
    assert!(HK_FIELDS.iter().all(|f| type_len(f.1) > 0));
    let attitude: usize = ATTITUDE_FIELDS.iter().map(|f| type_len(f.1)).sum();
    assert_eq!(attitude, ATTITUDE_LEN);
    // The busiest packet, a full star list, fits the packet and the queue.
    let list = 7 + p::MAX_LINK_STARS * p::STAR_BYTES;
    assert!(6 + 7 + p::TIMESTAMP_LEN + list + 2 <= p::MAX_TM_LEN);
    // Every telecommand type is distinct.
    for (i, a) in p::MESSAGES.iter().enumerate() {
        for b in &p::MESSAGES[i + 1..] {
            assert!(
                a.direction != b.direction || a.kind != b.kind || a.apid != b.apid,
                "{a:?} {b:?}"
            );
        }
    }
}

#[test]
fn protocol_page_is_generated_from_the_definition() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/protocol.md");
    let text = std::fs::read_to_string(&path).expect("docs/protocol.md");
    let (head, rest) = text.split_once(BEGIN).expect("generated-block marker");
    let (_, tail) = rest.split_once(END).expect("end marker");
    let want = format!("{head}{BEGIN}\n\n{}\n{END}{tail}", render());
    if std::env::var_os("UPDATE_DOCS").is_some() {
        std::fs::write(&path, &want).expect("write docs/protocol.md");
        return;
    }
    assert!(
        text == want,
        "docs/protocol.md is out of date: UPDATE_DOCS=1 cargo test -p startrack-host --test link link_protocol_doc::"
    );
}
