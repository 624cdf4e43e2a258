//! Newtype identifiers, so an image id can never be passed where a point id is expected.

use serde::{Deserialize, Serialize};
use std::fmt;

macro_rules! newtype_id {
    ($(#[$doc:meta])* $name:ident, $inner:ty) => {
        $(#[$doc])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize, Default)]
        #[serde(transparent)]
        pub struct $name(pub $inner);

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                write!(f, "{}", self.0)
            }
        }

        impl From<$inner> for $name {
            fn from(v: $inner) -> Self {
                Self(v)
            }
        }
    };
}

newtype_id!(
    /// One input image or video frame.
    ImageId,
    u32
);
newtype_id!(
    /// One intrinsics group (a physical camera at one zoom setting); many images may share it.
    CameraId,
    u32
);
newtype_id!(
    /// One reconstructed 3D point (and its track).
    PointId,
    u64
);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_distinct_types_and_print_plainly() {
        let i = ImageId(7);
        assert_eq!(i.to_string(), "7");
        assert!(ImageId(1) < ImageId(2));
        assert_eq!(serde_json_like(PointId(42)), "42");
    }

    fn serde_json_like(p: PointId) -> String {
        p.0.to_string()
    }
}
