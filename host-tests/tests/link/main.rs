//! The link and the table store: the receive side, the protocol document, the served SIL with
//! its ground clients, and the store on the H7 flash model.
//!
//! One module per subject, each with its own module docs; the shared f64 references and table
//! fixtures come from `startrack-test-support`.

mod link_decoder;
mod link_flash_power_cut;
mod link_flash_upload;
mod link_ground_upload;
mod link_pil_power_cut;
mod link_pipe;
mod link_protocol_doc;
mod link_python;
mod link_sil;
mod link_soak;
mod link_standby;
mod served;
mod store_api;
mod store_power_cut;
mod store_props;
mod time_cuc;
