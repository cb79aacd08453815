/// Description of the type of a [Topic](../struct.Topic.html)
#[derive(Clone, PartialEq, Eq, Debug)]
pub struct TypeDesc {
  my_name: String, // this is a rather minimal implementation
} // placeholders

impl TypeDesc {
  pub fn new(my_name: String) -> Self {
    Self { my_name }
  }
  pub fn name(&self) -> &str {
    &self.my_name
  }
}

// mode360 patch: the USER_DATA that every local endpoint of a type announces.
//
// ROS 2 (REP 2011) puts each endpoint's type hash in its USER_DATA QoS
// (`typehash=RIHS01_<hex>;`), and the hash is a property of the type. ros2-client
// creates some endpoints itself (parameter services, `/rosout`,
// `/parameter_events`, `ros_discovery_info`), so the application registers the
// USER_DATA per DDS type name here, before it creates its endpoints, and
// discovery announces it for every local reader and writer of that type.

use std::{collections::BTreeMap, sync::RwLock};

static ENDPOINT_USER_DATA: RwLock<BTreeMap<String, Vec<u8>>> = RwLock::new(BTreeMap::new());

/// Sets the USER_DATA octets that local readers and writers of the DDS type
/// `type_name` (e.g. `sensor_msgs::msg::dds_::Image_`) announce in discovery
/// from now on. An empty `user_data` announces none.
pub fn set_endpoint_user_data(type_name: &str, user_data: Vec<u8>) {
  let mut map = ENDPOINT_USER_DATA
    .write()
    .unwrap_or_else(|poisoned| poisoned.into_inner());
  if user_data.is_empty() {
    map.remove(type_name);
  } else {
    map.insert(type_name.to_string(), user_data);
  }
}

/// The USER_DATA octets registered for `type_name` (empty if none).
pub fn endpoint_user_data(type_name: &str) -> Vec<u8> {
  ENDPOINT_USER_DATA
    .read()
    .unwrap_or_else(|poisoned| poisoned.into_inner())
    .get(type_name)
    .cloned()
    .unwrap_or_default()
}
