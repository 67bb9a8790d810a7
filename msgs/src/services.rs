//! The ROS 2 services Revisit's nodes serve: a request and a response type per service, each
//! mirroring its `.srv` file (`interfaces/std_srvs/srv/` for ROS's own, `revisit_msgs/srv/` for
//! Revisit's).

use serde::{de::DeserializeOwned, Deserialize, Serialize};

/// A service type: its full ROS name, its `.srv` text, its request and response.
pub trait Service: 'static {
    /// The full ROS type name, e.g. `std_srvs/srv/Trigger`.
    const NAME: &'static str;
    /// The `.srv` file's text.
    const TEXT: &'static str;
    type Request: Serialize + DeserializeOwned + Clone + Send + 'static;
    type Response: Serialize + DeserializeOwned + Clone + Send + 'static;
}

/// `std_srvs/srv/Trigger`: do something now, say whether it worked.
pub struct Trigger;

/// An empty request (IDL gives an empty structure this one member).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TriggerRequest {
    pub structure_needs_at_least_one_member: u8,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TriggerResponse {
    pub success: bool,
    pub message: String,
}

impl Service for Trigger {
    const NAME: &'static str = "std_srvs/srv/Trigger";
    const TEXT: &'static str = include_str!("../interfaces/std_srvs/srv/Trigger.srv");
    type Request = TriggerRequest;
    type Response = TriggerResponse;
}

/// `revisit_msgs/srv/Save`: write the map to a folder.
pub struct Save;

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SaveRequest {
    pub directory: String,
}

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SaveResponse {
    pub success: bool,
    pub message: String,
}

impl Service for Save {
    const NAME: &'static str = "revisit_msgs/srv/Save";
    const TEXT: &'static str = include_str!("../revisit_msgs/srv/Save.srv");
    type Request = SaveRequest;
    type Response = SaveResponse;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Rust fields are the `.srv` fields (by name: JSON objects here are sorted).
    #[test]
    fn types_mirror_their_srv_files() {
        fn fields(text: &str) -> [Vec<String>; 2] {
            let (request, response) = text.split_once("---").unwrap_or((text, ""));
            let names = |part: &str| {
                let mut names: Vec<String> = part
                    .lines()
                    .map(|l| l.split('#').next().unwrap_or("").trim())
                    .filter(|l| !l.is_empty())
                    .filter_map(|l| l.split_whitespace().nth(1).map(str::to_owned))
                    .collect();
                names.sort();
                names
            };
            [names(request), names(response)]
        }
        fn serde_fields<T: Serialize + Default>() -> Vec<String> {
            match serde_json::to_value(T::default()) {
                Ok(serde_json::Value::Object(map)) => map.keys().cloned().collect(),
                _ => Vec::new(),
            }
        }
        assert_eq!(fields(Save::TEXT), [serde_fields::<SaveRequest>(), serde_fields::<SaveResponse>()]);
        let [request, response] = fields(Trigger::TEXT);
        assert!(request.is_empty());
        assert_eq!(response, serde_fields::<TriggerResponse>());
    }
}
