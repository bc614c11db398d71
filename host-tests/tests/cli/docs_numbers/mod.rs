//! The numbers of `README.md` and `docs/*.md` against the committed outputs they come from
//! (`host-tests/m7-costs.csv`, `host-tests/figures/*.csv`) or the code, so that a regenerated
//! CSV that changes them fails here until the page follows. One file per page; a table the
//! docs mark with `<!-- checked: NAME -->` on the line before it is parsed and each of its
//! cells compared with its source.

mod helpers;

mod accuracy;
mod attitude;
mod figures;
mod formats;
mod hardware;
mod pages;
mod readme;
mod sequencer;
mod speed;
mod tracker;
