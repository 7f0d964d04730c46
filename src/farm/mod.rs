//! Rendering on a farm: frame lists and the frame token, the split of a render into
//! tasks an engine runs by index, part files of partial sums and their exact merge.
//! ppb schedules nothing itself: Slurm, OpenJD or Kubernetes run the tasks (the job
//! files are written by the `ppb farm` command).
pub mod part;
pub mod tasks;

pub use part::{merge, Part, PartHeader};
pub use tasks::{PassRange, Task, Tasks};
