"""navigate: integration, drift, evaluation, strapdown, zero-velocity updates, online correction and tracks vs truth. Imports core, store and calibrate."""
