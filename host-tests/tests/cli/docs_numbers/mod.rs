//! The numbers of `README.md` and `docs/*.md` against the committed outputs they come from.

mod accuracy;
