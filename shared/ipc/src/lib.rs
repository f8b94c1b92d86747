//! Zero-copy iceoryx2 messages and transport helpers of the psgrasp pipeline
