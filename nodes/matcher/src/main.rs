//! `revisit-matcher [--ros-args ...]`: the matcher node (see the library's documentation).

use revisit_node::{Node, RosArgs};

fn main() -> anyhow::Result<()> {
    revisit_node::init_logging();
    let (_, args) = RosArgs::split(std::env::args().skip(1))?;
    tokio::runtime::Runtime::new()?.block_on(async {
        let mut node = Node::start(revisit_matcher_node::NAME, &args)?;
        let summary = revisit_matcher_node::run(&mut node).await;
        node.shutdown().await;
        tracing::info!("{}", summary?);
        Ok(())
    })
}
