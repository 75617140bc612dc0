//! diffphys facade
