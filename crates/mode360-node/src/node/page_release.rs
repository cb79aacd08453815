//! Handing freed memory back to the kernel, which only the allocator can do, and the allocator
//! is the binary's business: `src/main.rs` allocates with jemalloc and registers its purge
//! here ([`set_page_release`]); the library calls [`release_freed_pages`] when memory was freed
//! for good (a live-view client gone, `live_view.rs`). A process that registers nothing (a
//! test, another binary with the system allocator) releases nothing and pays nothing.

use std::sync::OnceLock;

/// Hands the allocator's free pages back to the kernel; true when it did.
pub type PageRelease = fn() -> bool;

static PAGE_RELEASE: OnceLock<PageRelease> = OnceLock::new();

/// Registers how this process releases freed pages; false when one was registered already
/// (the first stays).
pub fn set_page_release(release: PageRelease) -> bool {
    PAGE_RELEASE.set(release).is_ok()
}

/// Releases the allocator's free pages through the registered function, so the resident size
/// drops to what is in use; false when none is registered or it released nothing. The next
/// allocations fault their pages in again, so this runs when memory was freed for good, never
/// per frame.
pub fn release_freed_pages() -> bool {
    PAGE_RELEASE.get().is_some_and(|release| release())
}
