//! The InferenceBackend trait and the analytic antipodal backend
