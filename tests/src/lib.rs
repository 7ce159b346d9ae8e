//! machlink-tests: end-to-end tests that start the daemon and simulated devices and check
//! what the devices executed. The tests live in `tests/tests/`.
