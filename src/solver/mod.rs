//! Rigid-body solver: an immutable system description built from a model and
//! a reusable workspace; statics (Newton) and forward dynamics.
