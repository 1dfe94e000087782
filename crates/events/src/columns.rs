//! Events owned as columns (struct of arrays): what the simulator and the file decoders
//! produce, in the layout `EventSlice` reads and Python receives.

/// Events as columns: x, y (pixels), t (µs), p (the source's polarity value: 0/1 for CD
/// events, -1/+1 from the simulator).
#[derive(Debug, Default, Clone, PartialEq)]
pub struct Events {
    pub x: Vec<u16>,
    pub y: Vec<u16>,
    pub t: Vec<i64>,
    pub p: Vec<i8>,
}

impl Events {
    pub fn with_capacity(n: usize) -> Self {
        Self {
            x: Vec::with_capacity(n),
            y: Vec::with_capacity(n),
            t: Vec::with_capacity(n),
            p: Vec::with_capacity(n),
        }
    }

    pub fn len(&self) -> usize {
        self.t.len()
    }

    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    #[inline(always)]
    pub fn push(&mut self, x: u16, y: u16, t: i64, p: i8) {
        self.x.push(x);
        self.y.push(y);
        self.t.push(t);
        self.p.push(p);
    }
}
