//! ROS 2 services over `ros2-client`: a node serves requests of a `revisit-msgs` service type,
//! and a tool calls them. Services use ROS 2's default QoS (reliable, volatile, keep the last 10)
//! and the request-reply mapping of ROS 2's default middleware (Fast DDS's, DDS-RPC "enhanced"),
//! so `ros2 service call` on a ROS install reaches them.

use std::time::Duration;

use futures::{Stream, StreamExt};

use revisit_msgs::services::Service;
use ros2_client::{Name, ServiceMapping, ServiceTypeName};
use serde::{Deserialize, Serialize};

use crate::node::{dds, Node, RELIABLE};
use crate::NodeError;

/// A request or response as ros2-client carries it (its message trait, on a revisit-msgs type).
#[derive(Clone, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Wire<T>(T);

impl<T: Serialize + serde::de::DeserializeOwned> ros2_client::Message for Wire<T> {}

/// Who asked, to send the response to.
pub type RequestId = ros2_client::RmwRequestId;

/// A service the node serves.
pub struct Server<S: Service>(ros2_client::Server<Wire<S::Request>, Wire<S::Response>>);

impl<S: Service> Server<S> {
    /// The requests, as they come (select on it beside the node's topics).
    pub fn requests(&self) -> impl Stream<Item = Result<(RequestId, S::Request), NodeError>> + '_ {
        self.0.receive_request_stream().map(|request| request.map(|(id, Wire(request))| (id, request)).map_err(dds))
    }

    pub async fn respond(&self, id: RequestId, response: S::Response) -> Result<(), NodeError> {
        self.0.async_send_response(id, Wire(response)).await.map_err(dds)
    }
}

/// A caller of a service.
pub struct Client<S: Service> {
    client: ros2_client::Client<Wire<S::Request>, Wire<S::Response>>,
    /// The service's resolved name.
    name: String,
}

impl<S: Service> Client<S> {
    /// Waits up to `timeout` for a server, sends `request`, and waits (as long as the server
    /// works on it) for the response.
    pub async fn call(&self, node: &Node, request: S::Request, timeout: Duration) -> Result<S::Response, NodeError> {
        tokio::time::timeout(timeout, self.client.wait_for_service(node.ros())).await.map_err(|_| {
            NodeError::Dds(format!("no server of {} ({}) appeared within {timeout:?}", self.name, S::NAME))
        })?;
        let Wire(response) = self.client.async_call_service(Wire(request)).await.map_err(dds)?;
        Ok(response)
    }
}

impl Node {
    /// Serves service `S` as `name` (resolved and remapped as topics are, `~/save` under the
    /// node's name).
    pub fn server<S: Service>(&mut self, name: &str) -> Result<Server<S>, NodeError> {
        let (name, type_name) = self.service_names::<S>(name)?;
        let server = self.ros_mut().create_server(ServiceMapping::Enhanced, &name, &type_name, RELIABLE, RELIABLE);
        Ok(Server(server.map_err(dds)?))
    }

    /// A client of service `S` named `name`.
    pub fn client<S: Service>(&mut self, name: &str) -> Result<Client<S>, NodeError> {
        let (resolved, type_name) = self.service_names::<S>(name)?;
        let client = self.ros_mut().create_client(ServiceMapping::Enhanced, &resolved, &type_name, RELIABLE, RELIABLE);
        Ok(Client { client: client.map_err(dds)?, name: self.names().resolve(name)? })
    }

    fn service_names<S: Service>(&self, name: &str) -> Result<(Name, ServiceTypeName), NodeError> {
        let resolved = self.names().resolve(name)?;
        let name = Name::parse(&resolved).map_err(|e| NodeError::Args(format!("service {resolved:?}: {e}")))?;
        let (package, ty) = match S::NAME.split('/').collect::<Vec<_>>()[..] {
            [package, "srv", ty] => (package, ty),
            _ => return Err(NodeError::Args(format!("{:?} is not a service type name (pkg/srv/Type)", S::NAME))),
        };
        Ok((name, ServiceTypeName::new(package, ty)))
    }
}
