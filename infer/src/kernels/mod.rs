//! The project's own CPU kernels and their plumbing into Burn's flex
//! backend: GEMM and direct convolutions with their gradients, native
//! RoIAlign and max pooling with their backward passes, the switch that
//! turns them on, and the allocator settings they rely on. The networks
//! reach them only through `conv_op`, `roi_align` and `max_pool_native`.

pub mod allocator;
pub mod conv_kernels;
pub mod conv_op;
pub mod cpu_kernels;
pub mod direct_conv;
pub mod max_pool_native;
pub mod roi_align_native;
