// TEMPORARY stub in the ops worktree (set by the lead): the real CLI lives on main and needs
// modules from other branches. Do not edit; it is resolved at merge time.
fn main() {}
